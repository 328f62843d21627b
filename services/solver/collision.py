"""Self-collision avoidance: velocity dampers on the signed distances of the profile's link pairs.

For every pair of collision geoms (a, b) of the profile's ``[collision]`` pairs closer than the
influence distance ``d_i``, with signed distance ``d`` and witness points ``p_a``, ``p_b``
(MuJoCo's ``mj_geomDistance`` on the robot's URDF collision meshes), the joint velocities must
satisfy the damper (Faverjon & Tournassoud; Kanoun et al.)

    d_dot = n^T (J_b(p_b) - J_a(p_a)) qd >= -xi (d - d_s) / (d_i - d_s)

with ``n`` the unit vector from ``p_a`` to ``p_b`` for a separated pair (the direction in which
``d`` grows, also when penetrating), ``J(p)`` (3, n) the Jacobian of the witness point on its link
and ``d_s`` the safety distance: a pair may approach at ``xi`` [m/s] at ``d_i`` and not at all at
``d_s``; closer than ``d_s`` it must separate. The rows go to the solver as ``G qd <= h``, hard at
every priority level (``inequalities.Inequalities``).

The geometry and the witness Jacobians come from a MuJoCo model of the same URDF
(``shared.robot.mujoco_model``) kept for kinematics only: its controlled joints are set from the
solver's q, the rest stay at the profile's rest pose (as in the reduced Pinocchio model). The base
is welded in both models, so MuJoCo's world frame moves with the pelvis and distances and their
rates are the same in either frame. A broad phase on bounding spheres skips the pairs that are
clearly farther than ``d_i`` before any ``mj_geomDistance`` call.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from services.solver.inequalities import Inequalities
from shared.robot.mujoco_model import build_mujoco_robot
from shared.robot.pinocchio_model import RobotModel
from shared.robot.profile import CollisionSpec

#: Pair distances below this [m] have no reliable witness direction: the geoms' centres give it.
DEGENERATE = 1e-6


@dataclass(slots=True)
class PairDistance:
    """One checked geom pair: geom ids, signed distance d [m] and witness points (3,) [m] (world frame)."""

    geom_a: int
    geom_b: int
    distance: float
    p_a: np.ndarray
    p_b: np.ndarray


class SelfCollisionAvoidance:
    """Damper rows ``G qd <= h`` for a robot's self-collision pairs at a configuration.

    Args:
        robot: the solver's reduced model (its joint order is the order of q and of G's columns).
        spec: the pairs and damper parameters (default: the profile's ``[collision]``).

    Raises:
        ValueError: no spec, or a link of the spec without collision geometry in the model.
    """

    def __init__(self, robot: RobotModel, spec: CollisionSpec | None = None):
        spec = spec or robot.profile.collision
        if spec is None:
            raise ValueError(f"robot profile {robot.profile.name} has no [collision] table")
        self.spec = spec
        self.mj = build_mujoco_robot(robot.profile, joint_names=robot.joint_names)
        m = self.model = self.mj.model
        self.data = mujoco.MjData(m)
        self.data.qpos[:] = self.mj.data.qpos  # every joint at rest
        self.qpos_idx = self.mj.qpos_idx
        self.dof_idx = self.mj.dof_idx
        collides = (m.geom_contype != 0) | (m.geom_conaffinity != 0)
        geoms: dict[str, list[int]] = {}
        for group, links in spec.groups.items():
            ids = []
            for link in links:
                try:
                    body = m.body(link).id
                except KeyError:
                    raise ValueError(f"[collision] group {group}: link {link!r} is not in the model") from None
                ids += [g for g in range(m.ngeom) if m.geom_bodyid[g] == body and collides[g]]
            if not ids:
                raise ValueError(f"[collision] group {group}: none of {list(links)} has collision geometry")
            geoms[group] = ids
        pairs = {(min(a, b), max(a, b)) for ga, gb in spec.pairs for a in geoms[ga] for b in geoms[gb] if a != b}
        self.pairs = np.array(sorted(pairs), dtype=int).reshape(-1, 2)
        # The pairs' geoms, and each one's bounding box (MuJoCo's geom_aabb: centre and half sizes in the
        # geom frame); pairs index into them.
        self._geoms, inverse = np.unique(self.pairs, return_inverse=True)
        self._pair_a, self._pair_b = inverse.reshape(-1, 2).T.copy()
        self._box_c = m.geom_aabb[self._geoms, :3, None].copy()
        self._box_h = m.geom_aabb[self._geoms, 3:].copy()
        self.d_s = spec.safety_distance
        self.d_i = spec.influence_distance
        self.xi = spec.damper_speed
        self._fromto = np.zeros(6)
        self._com_ready = False
        self._jac_a = np.zeros((3, m.nv))
        self._jac_b = np.zeros((3, m.nv))
        #: pair distances of the last ``rows`` call, closest first (pairs within d_i only)
        self.close: list[PairDistance] = []
        self.min_distance = np.inf
        self.candidates = 0

    def set_q(self, q: np.ndarray) -> None:
        """Kinematics of the MuJoCo model at the solver's q (n,) [rad]."""
        self.data.qpos[self.qpos_idx] = q
        mujoco.mj_kinematics(self.model, self.data)
        self._com_ready = False

    def lower_bounds(self) -> np.ndarray:
        """(P,) lower bounds [m] of every pair's distance: the gap of their bounding boxes along the centre line.

        The boxes' supports along the unit vector u between their centres bound the geoms' extent along u,
        so ``u . (c_b - c_a) - s_a(u) - s_b(u)`` never exceeds the true distance.
        """
        d = self.data
        R = d.geom_xmat[self._geoms].reshape(-1, 3, 3)
        centre = d.geom_xpos[self._geoms] + np.matmul(R, self._box_c)[:, :, 0]
        a, b = self._pair_a, self._pair_b
        u = centre[b] - centre[a]
        dist = np.sqrt((u * u).sum(axis=1))
        u /= np.maximum(dist, DEGENERATE)[:, None]
        # support of box g along u: sum_k h_k |R[:, k] . u|
        s_a = (np.abs(np.matmul(u[:, None, :], R[a])[:, 0]) * self._box_h[a]).sum(axis=1)
        s_b = (np.abs(np.matmul(u[:, None, :], R[b])[:, 0]) * self._box_h[b]).sum(axis=1)
        return dist - s_a - s_b

    def distances(self, q: np.ndarray, dmax: float | None = None) -> list[PairDistance]:
        """Signed distances of the pairs within ``dmax`` [m] (default d_i) at q (n,) [rad], closest first."""
        self.set_q(q)
        return self._distances(self.d_i if dmax is None else dmax)

    def _distances(self, dmax: float) -> list[PairDistance]:
        m, d = self.model, self.data
        near = np.flatnonzero(self.lower_bounds() < dmax)
        self.candidates = near.size
        out = []
        for i in near:
            pd = pair_distance(m, d, int(self.pairs[i, 0]), int(self.pairs[i, 1]), dmax, self._fromto)
            if pd is not None:
                out.append(pd)
        out.sort(key=lambda pd: pd.distance)
        return out

    def body_names(self, pd: PairDistance) -> tuple[str, str]:
        """The links (bodies) of a pair."""
        m = self.model
        return m.body(int(m.geom_bodyid[pd.geom_a])).name, m.body(int(m.geom_bodyid[pd.geom_b])).name

    def rows(self, q: np.ndarray) -> Inequalities:
        """The damper rows ``G qd <= h`` (p, n) / (p,) at q (n,) [rad] for every pair within d_i."""
        self.set_q(q)
        close = self.close = self._distances(self.d_i)
        self.min_distance = close[0].distance if close else np.inf
        G = np.empty((len(close), self.dof_idx.shape[0]))
        h = np.empty(len(close))
        for r, pd in enumerate(close):
            G[r] = -self.distance_jacobian(pd)
            h[r] = self.xi * (pd.distance - self.d_s) / (self.d_i - self.d_s)
        return Inequalities(G, h)

    def distance_jacobian(self, pd: PairDistance) -> np.ndarray:
        """(n,) gradient of the pair's signed distance w.r.t. the solver's joints: d_dot = row @ qd.

        ``n^T (J_b(p_b) - J_a(p_a))`` with the witness points fixed on their links (kinematics at the
        last ``set_q``/``rows``).
        """
        if not self._com_ready:
            mujoco.mj_comPos(self.model, self.data)  # mj_jac reads cdof and subtree_com
            self._com_ready = True
        return distance_gradient(self.model, self.data, pd, self._jac_a, self._jac_b)[self.dof_idx]


def pair_distance(
    model: mujoco.MjModel, data: mujoco.MjData, a: int, b: int, dmax: float, fromto: np.ndarray | None = None
) -> PairDistance | None:
    """Signed distance [m] of geoms a and b and their witness points (world frame), or None beyond dmax [m].

    Kinematics (``mj_kinematics``) must be current. Negative: penetration depth.
    """
    ft = np.zeros(6) if fromto is None else fromto
    dist = mujoco.mj_geomDistance(model, data, a, b, dmax, ft)
    if dist >= dmax:
        return None
    return PairDistance(a, b, float(dist), ft[:3].copy(), ft[3:].copy())


def pair_normal(data: mujoco.MjData, pd: PairDistance) -> np.ndarray:
    """Unit vector (3,) (world frame) along which the pair's signed distance grows, from a towards b."""
    v = pd.p_b - pd.p_a
    if abs(pd.distance) > DEGENERATE:
        nv = np.linalg.norm(v)
        if nv > DEGENERATE:
            # p_b - p_a = d n: it points back from b to a when the pair penetrates (d < 0).
            return v / nv * np.sign(pd.distance)
    v = data.geom_xpos[pd.geom_b] - data.geom_xpos[pd.geom_a]
    return v / max(np.linalg.norm(v), DEGENERATE)


def distance_gradient(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    pd: PairDistance,
    jac_a: np.ndarray | None = None,
    jac_b: np.ndarray | None = None,
) -> np.ndarray:
    """(nv,) d(distance)/d(qpos velocity) of a pair: ``n^T (J_b(p_b) - J_a(p_a))``, witness points on their bodies.

    Needs ``mj_kinematics`` and ``mj_comPos`` current. jac_a, jac_b: optional (3, nv) buffers.
    """
    ja = np.zeros((3, model.nv)) if jac_a is None else jac_a
    jb = np.zeros((3, model.nv)) if jac_b is None else jac_b
    mujoco.mj_jac(model, data, ja, None, pd.p_a, int(model.geom_bodyid[pd.geom_a]))
    mujoco.mj_jac(model, data, jb, None, pd.p_b, int(model.geom_bodyid[pd.geom_b]))
    return pair_normal(data, pd) @ (jb - ja)
