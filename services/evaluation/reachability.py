"""Independent reachability check of published targets: position IK with Pinocchio.

The retargeter's own claim that a target is reachable is not evidence; this check is. For each
published wrist target (and optionally its elbow target with it) it runs damped least squares over
that arm's 7 joints within their limits (waist at rest, the set the retargeter promises), first
from the previous frame's solution, then from fixed seeds spread over the joint ranges. A target is
reachable when one of the runs ends within ``tol`` of it, and the robot hand posed at it is not inside
the robot's trunk (collision-aware: the IK alone would count a target in the belly as reached, and the
solver's self-collision dampers keep the hand out of it). The hand's distance to the trunk at the waist's
rest is the retargeter's (:class:`services.retarget.trunk.TrunkClearance`: the solver's link proxies, the
hand oriented as the target says, or as the IK left it when the target has no rotation); the other arm is
not checked (it moves).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from services.retarget.trunk import NoTrunkError, TrunkClearance
from shared.messages import TaskTargets
from shared.robot.pinocchio_model import RobotModel
from shared.rotations import quat_to_matrix

#: Distance under which IK counts a wrist target as reached [m].
IK_TOL = 1e-3
#: The same for a wrist + elbow pair [m]: the swivel elbow is placed around a fitted shoulder
#: centre (the G1's shoulder axes do not intersect), which leaves a few millimetres.
PAIR_TOL = 0.01
SIDES = ("left", "right")
#: Hand-to-trunk distance [m] below which a wrist target counts as inside the body, hence not reachable.
BODY_TOL = 0.0
#: profile source -> its trunk distance (built once: the proxies take ~1-3 s)
_TRUNKS: dict[str, TrunkClearance | None] = {}


@dataclass
class ArmIk:
    """Damped least-squares position IK of one arm (``side``) of a reduced model (waist at rest).

    Attributes:
        robot: reduced model (its non-arm joints stay at rest).
        side: "left" or "right".
        seeds: (S, n) start configurations tried after the warm start.
    """

    robot: RobotModel
    side: str
    n_seeds: int = 6
    iters: int = 80
    damping: float = 1e-3
    arm: np.ndarray = field(init=False)
    seeds: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        r = self.robot
        self.arm = np.array(
            [i for i, n in enumerate(r.joint_names) if n.startswith(f"{self.side}_") and "waist" not in n]
        )
        rng = np.random.default_rng(0)
        base = np.tile(r.q_rest, (self.n_seeds, 1))
        lo, hi = r.lower[self.arm], r.upper[self.arm]
        base[:, self.arm] = lo + rng.uniform(0.15, 0.85, (self.n_seeds, len(self.arm))) * (hi - lo)
        self.seeds = np.vstack([r.q_rest, base])
        self.data = r.model.createData()
        self.fids = {k: r.frame_id(f"{self.side}_{k}") for k in ("wrist", "elbow")}

    def solve(
        self, wrist: np.ndarray, elbow: np.ndarray | None = None, q0: np.ndarray | None = None, tol: float = IK_TOL
    ) -> tuple[float, np.ndarray]:
        """Best IK from ``q0`` then the seeds: (residual [m] = largest frame distance, q (n,))."""
        goals = [(self.fids["wrist"], np.asarray(wrist, dtype=float))]
        if elbow is not None:
            goals.append((self.fids["elbow"], np.asarray(elbow, dtype=float)))
        best = (np.inf, self.robot.q_rest)
        # a pair is checked from the warm start and the rest pose only: it is nearly determined by the
        # wrist (one swivel), and failing pairs would otherwise cost every seed on every frame
        seeds = self.seeds[:1] if elbow is not None else self.seeds
        starts = ([q0] if q0 is not None else []) + list(seeds)
        for q in starts:
            res, q = self._dls(q.copy(), goals, tol)
            if res < best[0]:
                best = (res, q)
            if res <= tol:
                break
        return best

    def _dls(self, q: np.ndarray, goals, tol: float) -> tuple[float, np.ndarray]:
        r, d, arm = self.robot, self.data, self.arm
        lo, hi = r.lower[arm], r.upper[arm]
        res = np.inf
        for _ in range(self.iters):
            pin.computeJointJacobians(r.model, d, q)  # also the joint placements (forward kinematics)
            errs = [p - pin.updateFramePlacement(r.model, d, f).translation for f, p in goals]
            res = max(float(np.linalg.norm(e)) for e in errs)
            if res <= tol:
                break
            e = np.concatenate(errs)
            J = np.vstack([pin.getFrameJacobian(r.model, d, f, pin.LOCAL_WORLD_ALIGNED)[:3, arm] for f, _ in goals])
            # damped least squares, the damping growing with the error (Levenberg style)
            lam = self.damping * min(1.0, 10.0 * res) + 1e-7
            dq = J.T @ np.linalg.solve(J @ J.T + lam * np.eye(len(e)), e)
            n = np.linalg.norm(dq)
            if n > 0.5:
                dq *= 0.5 / n
            q[arm] = np.clip(q[arm] + dq, lo, hi)
        return res, q


@dataclass
class ReachabilityReport:
    """Per published frame and arm: IK residuals [m] of the wrist alone and of the wrist with its elbow.

    Attributes:
        seq: (F,) frame seq. wrist_res, pair_res: side -> (F,) residual [m] (NaN: target invalid).
        speed: side -> (F,) fastest shoulder/elbow joint speed [rad/s] between consecutive wrist + elbow
            IK solutions (each warm-started from the previous: the nearest posture), NaN where unknown.
            Above the joint speed cap a target is reachable in place but not in time.
        vmax: the arm joints' speed cap [rad/s].
        body_dist: side -> (F,) signed distance [m] from the robot hand posed at the wrist target to the trunk at
            the waist's rest (capped a few cm beyond the safety distance; NaN: target invalid). Empty: not
            checked. Below ``body_tol`` the target is inside the body: not reachable, whatever the IK says.
        safety_distance: the solver's self-collision safety distance [m] (``in_body`` counts within it too).
    """

    seq: np.ndarray
    wrist_res: dict[str, np.ndarray]
    pair_res: dict[str, np.ndarray]
    speed: dict[str, np.ndarray] = field(default_factory=dict)
    vmax: float = np.inf
    tol: float = IK_TOL
    pair_tol: float = PAIR_TOL
    body_dist: dict[str, np.ndarray] = field(default_factory=dict)
    body_tol: float = BODY_TOL
    safety_distance: float = 0.0

    def inside(self) -> dict[str, np.ndarray]:
        """side -> (F,) bool, the wrist target puts the hand inside the body (False where unchecked or invalid)."""
        return {s: np.nan_to_num(d, nan=np.inf) < self.body_tol for s, d in self.body_dist.items()}

    def near_body(self) -> dict[str, np.ndarray]:
        """side -> (F,) bool, the wrist target puts the hand inside the body or within the solver's safety distance
        of it, where its self-collision dampers hold the hand off (False where unchecked or invalid)."""
        tol = max(self.body_tol, self.safety_distance)
        return {s: np.nan_to_num(d, nan=np.inf) < tol for s, d in self.body_dist.items()}

    def reachable(self, pair: bool = False) -> dict[str, np.ndarray]:
        """side -> (F,) bool, the target (pair) reached within tol with the hand outside the body; invalid targets
        count as reachable."""
        src, tol = (self.pair_res, self.pair_tol) if pair else (self.wrist_res, self.tol)
        inside = self.inside()
        return {s: ~(np.nan_to_num(r, nan=0.0) > tol) & ~inside.get(s, False) for s, r in src.items()}

    def fraction(self, pair: bool = False) -> float:
        """Reachable share of the valid targets over both arms (a target inside the body is not reachable)."""
        src = self.pair_res if pair else self.wrist_res
        ok = self.reachable(pair)
        vals = np.concatenate([ok[s][np.isfinite(r)] for s, r in src.items()])
        return float(np.mean(vals)) if vals.size else 1.0

    def in_body(self) -> dict:
        """Counts of published frames whose wrist target puts the hand inside the body (either arm), within the
        solver's safety distance of it, and the smallest hand-to-trunk distance [cm] (None: unchecked)."""
        if not self.body_dist:
            return {"frames_inside": None, "frames_within_safety": None, "min_distance_cm": None}
        d = np.vstack([np.nan_to_num(v, nan=np.inf) for v in self.body_dist.values()]).min(axis=0)
        return {
            "frames_inside": int(np.sum(d < self.body_tol)),
            "frames_within_safety": int(np.sum(d < self.safety_distance)),
            "min_distance_cm": float(100.0 * d.min()) if np.isfinite(d).any() else None,
        }

    def speed_feasible_fraction(self) -> float | None:
        """Share of frames (both arms) whose IK posture change stays within the joint speed cap."""
        vals = np.concatenate([v[np.isfinite(v)] for v in self.speed.values()]) if self.speed else np.zeros(0)
        return float(np.mean(~self._over_speed(vals))) if vals.size else None

    def too_fast(self) -> dict[str, np.ndarray]:
        """side -> (F,) bool, the arm's IK posture change to this frame is beyond the joint speed cap (reachable in
        place, not in time; False where unknown)."""
        return {s: self._over_speed(np.nan_to_num(v, nan=0.0)) for s, v in self.speed.items()}

    def _over_speed(self, speed: np.ndarray) -> np.ndarray:
        return speed > self.vmax * (1 + 1e-6)


def trunk_for(robot: RobotModel) -> TrunkClearance | None:
    """The hand-to-trunk distance of a robot at its waist's rest (cached per profile), None when its profile gives
    no trunk (:class:`~services.retarget.trunk.NoTrunkError`)."""
    key = f"{robot.profile.source}:{','.join(robot.joint_names)}"
    if key not in _TRUNKS:
        try:
            prof = robot.profile
            _TRUNKS[key] = TrunkClearance(
                robot,
                {s: prof.frames[f"{s}_wrist"] for s in SIDES},
                hand_frames={s: prof.orientation_frame(f"{s}_wrist") for s in SIDES},
            )
        except NoTrunkError:
            _TRUNKS[key] = None
    return _TRUNKS[key]


def check_targets(
    robot: RobotModel, targets: list[TaskTargets], pair: bool = True, body: bool = True
) -> ReachabilityReport:
    """IK-check every published wrist target (and wrist + elbow pair) of a stream.

    Args:
        robot: reduced model whose arms are checked (waist joints, if any, stay at rest).
        pair: also check the wrist and elbow targets together.
        body: also measure the hand's distance to the trunk at each wrist target (a target inside the body
            is not reachable; skipped when the profile has no ``[collision]`` table).
    """
    iks = {s: ArmIk(robot, s) for s in SIDES}
    trunk = trunk_for(robot) if body else None
    bdist = {s: np.full(len(targets), np.nan) for s in SIDES} if trunk is not None else {}
    F = len(targets)
    wres = {s: np.full(F, np.nan) for s in SIDES}
    pres = {s: np.full(F, np.nan) for s in SIDES}
    speed = {s: np.full(F, np.nan) for s in SIDES}
    last = {s: None for s in SIDES}  # (stamp, q) of the previous pair solution
    warm = {s: None for s in SIDES}
    warm_pair = {s: None for s in SIDES}
    # shoulder and elbow joints only: the wrist joints are free in the pair IK
    moved = {s: [i for i in iks[s].arm if "wrist" not in robot.joint_names[i]] for s in SIDES}
    for k, tt in enumerate(targets):
        for s in SIDES:
            w = tt.targets.get(f"{s}_wrist")
            if w is None or not w.valid:
                continue
            res, q = iks[s].solve(w.p, q0=warm[s])
            wres[s][k] = res
            warm[s] = q
            e = tt.targets.get(f"{s}_elbow")
            if trunk is not None:
                elbow_ok = e is not None and e.valid
                # the IK posture's frames only where the targets lack them (most frames need none)
                need = ([] if w.use_rotation else [f"{s}_wrist"]) + ([] if elbow_ok else [f"{s}_elbow"])
                pose = robot.frame_poses(q, names=tuple(need)) if need else {}
                elbow = np.asarray(e.p) if elbow_ok else pose[f"{s}_elbow"][0]
                # the hand as the target turns it, else as the IK left it
                R = quat_to_matrix(w.q) if w.use_rotation else pose[f"{s}_wrist"][1]
                bdist[s][k] = trunk.nearest(s, w.p, R, np.asarray(w.p) - elbow)[0]
            if pair and e is not None and e.valid:
                res, q = iks[s].solve(w.p, e.p, q0=warm_pair[s] if warm_pair[s] is not None else warm[s], tol=PAIR_TOL)
                pres[s][k] = res
                warm_pair[s] = q
                if last[s] is not None and tt.hdr.stamp > last[s][0]:
                    speed[s][k] = np.abs(q[moved[s]] - last[s][1][moved[s]]).max() / (tt.hdr.stamp - last[s][0])
                last[s] = (tt.hdr.stamp, q.copy())
    vmax = float(robot.vmax.min())
    d_s = robot.profile.collision.safety_distance if trunk is not None else 0.0
    seq = np.array([tt.hdr.seq for tt in targets])
    return ReachabilityReport(seq, wres, pres, speed, vmax, body_dist=bdist, safety_distance=d_s)
