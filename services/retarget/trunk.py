"""Wrist targets kept outside the robot's trunk (``RetargetConfig.trunk_clearance``; issue 12 item 4).

The operator's hands may rest on their belly or thighs, where the robot's trunk is thicker: mapped as they
are, such wrist targets put the robot's hand inside (or within the solver's safety distance of) its own
trunk. The solver's self-collision dampers then keep the hand out, and a strict HQP meets its wrist level
anyway by turning the waist: the waist moves the trunk and both arms rigidly, so it changes no arm-trunk
distance, but it carries the trunk away from a target fixed in the pelvis frame (call_normal_001: waist yaw
-40 deg, the elbow 14 cm off). A target inside the trunk is published on its surface instead:

    p' = p + t u,   t >= 0 such that d(p') = c   (where d(p) < c),

with ``d`` the signed distance [m] between the robot hand, posed at the target, and the nearest trunk link at the
waist's rest posture, and ``c`` the clearance (the profile's collision safety distance plus :data:`PAD`). Distances
are MuJoCo's ``mj_geomDistance`` on the solver's link proxies (:mod:`services.solver.collision`: convex polytopes
holding each link's mesh), penetration included. The hand is the wrist link (the target's position frame, the G1's
pitch link) and the link whose orientation the target gives, one joint past it (the yaw link, up to 9 cm from the
wrist point): the target fixes the second link's orientation, and the first sits between it and the forearm
(:class:`HandChain`). Until session 25 only the wrist link was posed, and at the hand's orientation, so its 7.5 cm
extent pointed wherever the hand did, off by the wrist yaw, and the hand past it was not checked: mink (no
self-collision avoidance) tracking the published targets touched the trunk on 68 sim steps of
wave-left-hand_masculine, 28 after (``mimic eval``). The exit direction ``u`` runs from the nearest point of the
central axis of the rigid body the link is on (the longest principal axis of that body's trunk proxies together,
within their extent) through the wrist link's centre: for a hand beside the torso that is the surface normal, and it
moves continuously with the target, so a target sliding into the body slides along its surface, and one past the
link's middle still leaves by the near side. (The distance's own gradient was tried first: where the hand overlaps a
link it is a face normal of the polytopes, which jumps between faces as the target moves, 5-14 mm between frames on
bow_old.) ``t`` is found by Newton steps kept within a bracket. A hand pushed frame after frame turns its ray from
the last one by :data:`EXIT_TURN` at most (:meth:`TrunkClearance.push` with ``prior``), so a target deep enough to
pass the axis goes round the body instead of leaving by the other side.

With ``fast_clearance`` the clearance depends on the hand's speed (:meth:`TrunkClearance.clearance_at`, the
speed low-passed by :class:`HandSpeed`): the full one for a resting hand, which must keep the solver's dampers
idle or the waist turns (above), a few millimetres for a swinging arm: a running arm passes the hips where the
operator's torso twists, the solver turns the robot's waist with it, and a target pushed out of the rest
trunk by the full clearance is one the arm no longer reaches (retarget README).
"""

from __future__ import annotations

import logging
import math

import mujoco
import numpy as np
import pinocchio as pin

from services.solver.collision import SelfCollisionAvoidance, add_proxy_geom, witness_normal
from shared.robot.pinocchio_model import RobotModel
from shared.rotations import cross3, matrix_to_quat

log = logging.getLogger(__name__)

#: Clearance [m] beyond the collision safety distance: a target exactly at the safety distance would hold the
#: solver's damper at its stop.
PAD = 0.005
#: Exit rays per target: the nearest link's, then the other links checked again (a hand between two links).
ITERATIONS = 3
#: Lower bound of the cosine between the exit ray and the distance's gradient (a Newton step is the distance
#: still to go over it).
EXIT_COS = 0.3
#: Newton (or bisection) steps along one exit ray, and the distance tolerance [m] that ends them.
NEWTON_STEPS = 12
TOL = 2e-4
#: Largest turn [rad] of a hand's exit ray between consecutive calls (15 deg): a target sliding deep into the torso
#: past its central axis (kick_normal's right hand across the chest) turned the ray from the front through the side
#: to the back in three frames, the published target 10-17 cm from the last one each time.
EXIT_TURN = math.radians(15.0)
#: Distance [m] beyond the clearance within which trunk links are measured (farther ones cannot bind).
LOOKOUT = 0.05


#: Hand speeds [m/s] up to which the full clearance is kept, and from which the fast one (``fast_clearance``):
#: resting hands (bow_old, call_normal_001, bow_feminine: 90 % of their frames near the trunk under 0.3 m/s)
#: keep the solver's dampers idle; a swinging arm (run_happy, dash_*: median 0.6-1.2 m/s there) only needs to
#: be published outside the rest trunk, which its waist moves anyway.
SLOW = 0.2
FAST = 0.6
#: Clearance [m] kept for a hand at FAST or faster by default (``RetargetConfig.trunk_clearance_fast``): a few
#: millimetres clear the rest trunk without moving a swinging arm's targets much farther than it
#: (session 12 measured 1 and 3 mm within a few per cent of each other; retarget README).
FAST_CLEARANCE = 0.003
#: Time constant [s] of the low-pass on the hand's speed (:class:`HandSpeed`): the clearance follows the arm's
#: swing, not one frame's finite difference.
SPEED_TAU = 0.1


class NoTrunkError(ValueError):
    """The robot profile gives no trunk for the hands to keep off (no ``[collision]`` table, no proxy for a wrist
    link, or no trunk link paired with the wrists)."""


class HandSpeed:
    """Low-passed speed [m/s] of one mapped wrist target (before the push), from consecutive positions."""

    def __init__(self, tau: float = SPEED_TAU):
        self.tau = tau
        self.reset()

    def reset(self) -> None:
        """Forget the history (a new stream, a gap): the next sample restarts from speed 0."""
        self._prev: np.ndarray | None = None
        self.speed = 0.0

    def update(self, p: np.ndarray, dt: float | None) -> float:
        """The filtered speed after position p (3,) [m], dt [s] after the previous one (None: restart)."""
        if self._prev is not None and dt is not None and dt > 0.0:
            raw = float(np.linalg.norm(p - self._prev)) / dt
            self.speed += (raw - self.speed) * (1.0 - math.exp(-dt / self.tau))
        elif dt is None:
            self.speed = 0.0
        self._prev = np.array(p, dtype=float)
        return self.speed


class HandChain:
    """How a hand link one revolute joint past the wrist link sits on it (the G1's wrist yaw link on the pitch link).

    The wrist target gives the wrist link's origin p and the hand link's orientation R; the joint between them
    is unknown, so the wrist link's orientation is chosen among those that joint allows as the one whose
    forward direction (towards the hand link's origin) is nearest the forearm's: on the G1 that is exact up
    to the elbow link's offset from the forearm (the sine of the wrist pitch is the forearm's component along
    the yaw axis, :mod:`.wrist_range`), and without it the wrist link's x axis would be taken as the hand's,
    off by the yaw angle.

    Args:
        robot: the robot model. wrist_link, hand_link: link names; exactly one joint of the model moves the
            hand link and not the wrist link, a revolute one whose axis runs through the hand link's origin.

    Raises:
        ValueError: the links are not one revolute joint apart.
    """

    def __init__(self, robot: RobotModel, wrist_link: str, hand_link: str):
        m = robot.model
        fw, fh = m.getFrameId(wrist_link), m.getFrameId(hand_link)
        between = [j for j in m.supports[m.frames[fh].parentJoint] if j not in m.supports[m.frames[fw].parentJoint]]
        if len(between) != 1 or m.joints[between[0]].nq != 1:
            raise ValueError(f"{hand_link!r} is not one revolute joint past {wrist_link!r}")
        j = m.joints[between[0]].idx_q
        data = m.createData()

        def poses(angle: float) -> tuple[pin.SE3, pin.SE3]:
            q = np.array(robot.q_rest, dtype=float)
            q[j] = angle
            pin.framesForwardKinematics(m, data, q)
            return data.oMf[fw].copy(), data.oMf[fh].copy()

        w0, h0 = poses(0.0)
        _, h1 = poses(0.1)
        rel = w0.actInv(h0)
        #: (3,) [m] the hand link's origin in the wrist link's frame
        self.offset = rel.translation.copy()
        #: (3, 3) the hand link's orientation in the wrist link's frame with the joint at 0
        self.R_rel = rel.rotation.copy()
        #: (3,) unit joint axis in the hand link's frame
        self.axis = pin.log3(h0.rotation.T @ h1.rotation) / 0.1
        self.axis /= np.linalg.norm(self.axis)
        if np.linalg.norm(h1.translation - h0.translation) > 1e-6:
            raise ValueError(f"the joint between {wrist_link!r} and {hand_link!r} moves the hand link's origin")
        #: (3,) the wrist link's forward direction (towards the hand link's origin) in the hand link's frame at 0
        self._forward = self.R_rel.T @ (self.offset / max(float(np.linalg.norm(self.offset)), 1e-9))

    def pose(self, p: np.ndarray, R: np.ndarray, forearm: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The wrist link's orientation (3, 3) and the hand link's origin (3,) [m] for the wrist link at p (3,) and
        the hand link at orientation R (3, 3) (base frame), the joint angle turning the wrist link's forward
        direction nearest to ``forearm`` (3,) (None, or along the axis: the joint at 0)."""
        theta = 0.0
        if forearm is not None:
            a, v, f = self.axis, self._forward, R.T @ np.asarray(forearm, dtype=float)
            v_perp, f_perp = v - (v @ a) * a, f - (f @ a) * a
            if f_perp @ f_perp > 1e-12 and v_perp @ v_perp > 1e-12:
                # the wrist link is the hand link turned back by the joint: its forward direction is v turned by -theta
                theta = -math.atan2(float(a @ cross3(v_perp, f_perp)), float(v_perp @ f_perp))
        R_wrist = R @ pin.exp3(-theta * self.axis) @ self.R_rel.T
        return R_wrist, p + R_wrist @ self.offset


class TrunkClearance:
    """Pushes wrist targets (robot base frame) out of the robot's trunk, held at the waist's rest posture.

    Args:
        robot: the model whose arms reach for the targets (the retargeter's: arms only; the solver's may hold
            the waist, which counts as trunk, not arm). Its profile's ``[collision]`` table gives the trunk (the
            links paired with the wrist link's group that no arm joint moves) and the safety distance.
        wrist_frames: side -> the wrist target's link (profile ``[frames]``).
        waist_carried: keep only the trunk links the waist moves (on the G1 torso, logo and head; not the
            pelvis), all rigid on the waist's last link, :attr:`carrier`. The trunk is still posed at the
            waist's rest: a caller with the waist elsewhere maps its targets into that pose
            (``services.solver.trunk_projection``).
        sca: the robot's self-collision model, whose link proxies are shared (default: one per robot model and
            process, built on first use, ~1.5 s); it is not changed.
        fast_clearance: [m] the clearance for a hand moving at :data:`FAST` or faster (:meth:`clearance_at`;
            None: the full clearance at every speed).
        hand_frames: side -> the link whose orientation is the wrist target's (profile ``[orientation_frames]``),
            when it is another link than the wrist link, one joint past it (the G1's yaw link, past the pitch
            link): it is posed too (:class:`HandChain`), so the whole hand keeps the clearance. None: the wrist
            link alone, posed at the orientation given.

    Raises:
        NoTrunkError: the profile has no ``[collision]`` table, or a wrist link has no collision proxy, or no trunk link
            is paired with the wrists (with ``waist_carried``: on the waist, or the profile has no waist).
        ValueError: ``fast_clearance`` outside (0, clearance].
    """

    def __init__(
        self,
        robot: RobotModel,
        wrist_frames: dict[str, str],
        waist_carried: bool = False,
        sca: SelfCollisionAvoidance | None = None,
        fast_clearance: float | None = None,
        hand_frames: dict[str, str] | None = None,
    ):
        if sca is None and robot.profile.collision is None:
            raise NoTrunkError(f"robot profile {robot.profile.name} has no [collision] table")
        sca = sca or _collision_model(robot)
        m = sca.model
        d = mujoco.MjData(m)  # its own data at the rest pose: the shared model's state is left alone
        d.qpos[:] = sca.data.qpos
        d.qpos[sca.qpos_idx] = robot.q_rest
        mujoco.mj_kinematics(m, d)
        waist = set(robot.profile.waist)
        arm_bodies = {m.jnt_bodyid[m.joint(j).id] for j in robot.joint_names if j not in waist}

        def moved_by_arm(body: int) -> bool:
            while body > 0:
                if body in arm_bodies:
                    return True
                body = m.body_parentid[body]
            return False

        spec = robot.profile.collision
        pairs = sca.link_pairs
        trunk: set[str] = set()
        for link in wrist_frames.values():
            if link not in sca.links:
                raise NoTrunkError(f"wrist link {link!r} has no collision proxy ([collision] groups)")
            i = sca.links.index(link)
            for a, b in pairs:
                other = sca.links[b] if a == i else sca.links[a] if b == i else None
                if other is not None and not moved_by_arm(m.body(other).id):
                    trunk.add(other)
        #: the body the waist's last joint moves, which carries the trunk links (``waist_carried``), else None
        self.carrier: str | None = None
        if waist_carried:
            if not waist:
                raise NoTrunkError(f"robot profile {robot.profile.name} has no waist to carry a trunk")
            # the waist joints form one chain: the deepest one's body carries everything the waist moves
            bodies = [m.jnt_bodyid[m.joint(j).id] for j in robot.profile.waist]
            carrier = max(bodies, key=lambda b: _depth(m, b))
            self.carrier = m.body(carrier).name
            trunk = {link for link in trunk if _on(m, m.body(link).id, carrier)}
        if not trunk:
            raise NoTrunkError("no trunk link is paired with the wrists in [collision]")
        #: the trunk links (sorted)
        self.trunk = sorted(trunk)
        #: [m] the clearance kept between the hand and the trunk
        self.clearance = spec.safety_distance + PAD
        if fast_clearance is not None and not 0.0 < fast_clearance <= self.clearance:
            raise ValueError(f"fast clearance {fast_clearance} must be in (0, {self.clearance}]")
        #: [m] the clearance kept for a hand at FAST or more (the full ``clearance`` up to SLOW)
        self.fast_clearance = self.clearance if fast_clearance is None else float(fast_clearance)
        ms = mujoco.MjSpec()
        for link in self.trunk:  # fixed where the rest posture puts them (pelvis = world)
            b = ms.worldbody.add_body()
            b.name = link
            bid = m.body(link).id
            b.pos, b.quat = d.xpos[bid], matrix_to_quat(d.xmat[bid].reshape(3, 3))
            add_proxy_geom(ms, link, sca.proxies[link])
        #: side -> the hand link one joint past the wrist link, and how it sits on it (None: the wrist link alone)
        self.chains: dict[str, HandChain | None] = {}
        for side, link in wrist_frames.items():
            b = ms.worldbody.add_body()
            b.name, b.mocap = f"hand:{side}", True
            add_proxy_geom(ms, b.name, sca.proxies[link])
            hand = (hand_frames or {}).get(side, link)
            chain = None
            if hand != link and hand in sca.proxies:
                try:
                    chain = HandChain(robot, link, hand)
                except ValueError as exc:  # another robot's wrist: the wrist link alone, as before
                    log.warning("trunk clearance poses the %s wrist link alone: %s", side, exc)
            if chain is not None:
                b = ms.worldbody.add_body()
                b.name, b.mocap = f"hand_link:{side}", True
                add_proxy_geom(ms, b.name, sca.proxies[hand])
            self.chains[side] = chain
        self.model = ms.compile()
        self.data = mujoco.MjData(self.model)
        self._trunk_geoms = [self.model.geom(f"polytope:{n}").id for n in self.trunk]
        #: trunk geom -> (centre (3,) [m], unit axis (3,), lo, hi [m]): the segment of the longest principal axis of
        #: the trunk proxies on its link's rigid body, together, within their extent (base frame), where the exit
        #: rays start. Per body, not per link: a small link on the body's surface (the G1's chest logo) has its
        #: longest axis in its own plane, sideways across the chest, so kick_normal's right hand, in front of the
        #: chest, was pushed 5-7 cm across it, and 5 cm back whenever the torso was the nearer link.
        self._axes = {}
        rigid: dict[int, list[tuple[str, int]]] = {}
        for link, g in zip(self.trunk, self._trunk_geoms, strict=True):
            rigid.setdefault(_rigid_root(m, m.body(link).id), []).append((link, g))
        for links in rigid.values():
            verts = np.vstack(
                [
                    d.xpos[bid] + sca.proxies[link].vertices() @ d.xmat[bid].reshape(3, 3).T
                    for link, bid in ((link, m.body(link).id) for link, _ in links)
                ]
            )
            centre = verts.mean(axis=0)
            axis = np.linalg.svd(verts - centre, full_matrices=False)[2][0]
            along = (verts - centre) @ axis
            for _, g in links:
                self._axes[g] = (centre, axis, float(along.min()), float(along.max()))
        #: side -> (wrist link geom id, mocap index)
        self._hand = {
            s: (self.model.geom(f"polytope:hand:{s}").id, int(self.model.body(f"hand:{s}").mocapid[0]))
            for s in wrist_frames
        }
        #: side -> (hand link geom id, mocap index), for the sides with a :class:`HandChain`
        self._hand_link = {
            s: (self.model.geom(f"polytope:hand_link:{s}").id, int(self.model.body(f"hand_link:{s}").mocapid[0]))
            for s, chain in self.chains.items()
            if chain is not None
        }
        self._fromto = np.zeros(6)

    def nearest(
        self, side: str, p: np.ndarray, R: np.ndarray, forearm: np.ndarray | None = None
    ) -> tuple[float, np.ndarray, int]:
        """The hand of ``side`` posed at p (3,) [m], R (3, 3) (base frame): its signed distance [m] to the nearest
        trunk link (capped at clearance + LOOKOUT), the unit direction (3,) along which it grows and that link's
        geom (-1: none within the cap). With a :class:`HandChain` on this side, ``R`` is the hand link's
        orientation, and ``forearm`` (3,) (the elbow-to-wrist direction, any length; None: unknown) sets how the
        wrist link sits between the forearm and the hand (:meth:`HandChain.pose`)."""
        g_hand, mocap = self._hand[side]
        chain = self.chains.get(side)
        geoms = [g_hand]
        self.data.mocap_pos[mocap] = p
        if chain is None:
            self.data.mocap_quat[mocap] = matrix_to_quat(R)
        else:
            R_wrist, p_hand = chain.pose(p, R, forearm)
            self.data.mocap_quat[mocap] = matrix_to_quat(R_wrist)
            g_link, mocap_link = self._hand_link[side]
            self.data.mocap_pos[mocap_link] = p_hand
            self.data.mocap_quat[mocap_link] = matrix_to_quat(R)
            geoms.append(g_link)
        mujoco.mj_kinematics(self.model, self.data)
        cap = self.clearance + LOOKOUT
        best, normal, geom = cap, np.zeros(3), -1
        xpos, rbound = self.data.geom_xpos, self.model.geom_rbound
        for gh in geoms:
            hand, r_hand = xpos[gh], rbound[gh]
            for g in self._trunk_geoms:
                c = xpos[g] - hand
                if math.sqrt(c @ c) - r_hand - rbound[g] >= best:  # their bounding spheres are already farther apart
                    continue
                dist = mujoco.mj_geomDistance(self.model, self.data, g, gh, cap, self._fromto)
                if dist < best:
                    best, geom = dist, g
                    normal = witness_normal(dist, self._fromto[:3], self._fromto[3:], xpos[g], xpos[gh])
        return float(best), normal, geom

    def _exit_ray(self, g: int, g_hand: int) -> np.ndarray:
        """(3,) unit direction out of trunk link geom ``g`` for the hand (kinematics done): from the nearest point
        of the link's central axis segment through the hand's centre."""
        centre, axis, lo, hi = self._axes[g]
        h = self.data.geom_xpos[g_hand]
        u = h - (centre + axis * np.clip((h - centre) @ axis, lo, hi))
        norm = float(np.linalg.norm(u))
        if norm > 1e-9:
            return u / norm
        forward = np.array([1.0, 0.0, 0.0]) - axis[0] * axis  # on the axis itself: out of the front
        return forward / np.linalg.norm(forward)

    def _along(
        self,
        side: str,
        p: np.ndarray,
        R: np.ndarray,
        u: np.ndarray,
        c: float,
        dist: float,
        n: np.ndarray,
        forearm: np.ndarray | None = None,
    ) -> np.ndarray:
        """The point p + t u (3,) [m], t > 0, where the hand's distance reaches ``c`` (``dist`` [m] and its direction
        ``n`` (3,) at p): Newton steps in t (the distance grows by u.n per metre), kept within the bracket of the
        points found inside and outside, else halving it. Unbracketed Newton could cycle: from deep in the torso a
        step lands past the lookout, where no link is measured and the slope is unknown, and the next comes back."""
        t, lo, hi = 0.0, 0.0, math.inf
        for _ in range(NEWTON_STEPS):
            t_new = t + (c - dist) / max(float(u @ n), EXIT_COS)  # inside (dist < c): always further out
            if not lo < t_new < hi:  # (so hi is finite here)
                t_new = 0.5 * (lo + hi)
            t = t_new
            dist, n, _ = self.nearest(side, p + t * u, R, forearm)
            if abs(dist - c) < TOL:
                return p + t * u
            if dist < c:
                lo = t
            else:
                hi = t
        return p + (hi if hi < math.inf else t) * u  # outside (at least c off) when a point there was found

    def clearance_at(self, speed: float) -> float:
        """The clearance [m] for a hand moving at ``speed`` [m/s]: ``clearance`` up to SLOW, ``fast_clearance``
        from FAST, a smoothstep in between (continuous in the speed, so the target moves with it smoothly)."""
        if self.fast_clearance == self.clearance or speed <= SLOW:
            return self.clearance
        if speed >= FAST:
            return self.fast_clearance
        x = (speed - SLOW) / (FAST - SLOW)
        return self.clearance + (self.fast_clearance - self.clearance) * x * x * (3.0 - 2.0 * x)

    def __call__(
        self, side: str, p: np.ndarray, R: np.ndarray, speed: float = 0.0, forearm: np.ndarray | None = None
    ) -> np.ndarray:
        """The wrist target p (3,) [m] with the hand (orientation R (3, 3); ``forearm`` as :meth:`nearest`) kept
        ``clearance_at(speed)`` off the trunk; ``p`` itself (the same object) when it already is."""
        return self.push(side, p, R, speed, forearm=forearm)[0]

    def push(
        self,
        side: str,
        p: np.ndarray,
        R: np.ndarray,
        speed: float = 0.0,
        prior: np.ndarray | None = None,
        forearm: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`__call__`, and the exit ray (3,) it pushed along (None: not pushed). With ``prior``, the ray of
        the same hand's previous push, the new ray turns from it by :data:`EXIT_TURN` at most."""
        out, used = p, None
        g_hand = self._hand[side][0]
        c = self.clearance_at(speed)
        for _ in range(ITERATIONS):
            dist, n, g = self.nearest(side, out, R, forearm)
            if dist >= c - TOL:
                break
            u = self._exit_ray(g, g_hand)
            if prior is not None:  # a hand past the link's axis keeps leaving the way it did
                u = _turn_towards(prior, u, EXIT_TURN)
            used = u if used is None else used
            out = self._along(side, out, R, u, c, dist, n, forearm)
        return out, used


def _turn_towards(a: np.ndarray, b: np.ndarray, limit: float) -> np.ndarray:
    """Unit a (3,) turned towards unit b (3,) by at most ``limit`` [rad] (a itself when b points away from it)."""
    c = float(np.clip(a @ b, -1.0, 1.0))
    if math.acos(c) <= limit:
        return b
    perp = b - c * a
    n = float(np.linalg.norm(perp))
    if n < 1e-9:
        return a
    return math.cos(limit) * a + math.sin(limit) * perp / n


#: (profile file, joints) -> the self-collision model whose proxies the pushes read (never changed by them), so a
#: process building several retargeters (the tests, ``mimic eval``) fits the proxies once
_COLLISION_MODELS: dict[tuple[str, tuple[str, ...]], SelfCollisionAvoidance] = {}


def _collision_model(robot: RobotModel) -> SelfCollisionAvoidance:
    """The robot's self-collision model (cached per profile file and joint list)."""
    key = (str(robot.profile.source), tuple(robot.joint_names))
    if key not in _COLLISION_MODELS:
        _COLLISION_MODELS[key] = SelfCollisionAvoidance(robot)
    return _COLLISION_MODELS[key]


def _depth(m: mujoco.MjModel, body: int) -> int:
    """Bodies between ``body`` and the world."""
    n = 0
    while body > 0:
        body, n = m.body_parentid[body], n + 1
    return n


def _rigid_root(m: mujoco.MjModel, body: int) -> int:
    """The body that ``body`` is rigidly part of: itself or its nearest ancestor with a joint (or on the world)."""
    while m.body_jntnum[body] == 0 and m.body_parentid[body] > 0:
        body = m.body_parentid[body]
    return body


def _on(m: mujoco.MjModel, body: int, carrier: int) -> bool:
    """``body`` is ``carrier`` or rigidly attached below it (no joint in between)."""
    while body != carrier:
        if body <= 0 or m.body_jntnum[body] > 0:
            return False
        body = m.body_parentid[body]
    return True
