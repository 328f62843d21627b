"""Independent reachability check of published targets: position IK with Pinocchio.

The retargeter's own claim that a target is reachable is not evidence; this check is. For each
published wrist target (and optionally its elbow target with it) it runs damped least squares over
that arm's 7 joints within their limits (waist at rest, the set the retargeter promises), first
from the previous frame's solution, then from fixed seeds spread over the joint ranges. A target is
reachable when one of the runs ends within ``tol`` of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from shared.messages import TaskTargets
from shared.robot.pinocchio_model import RobotModel

#: Distance under which IK counts a wrist target as reached [m].
IK_TOL = 1e-3
#: The same for a wrist + elbow pair [m]: the swivel elbow is placed around a fitted shoulder
#: centre (the G1's shoulder axes do not intersect), which leaves a few millimetres.
PAIR_TOL = 0.01
SIDES = ("left", "right")


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
    """

    seq: np.ndarray
    wrist_res: dict[str, np.ndarray]
    pair_res: dict[str, np.ndarray]
    speed: dict[str, np.ndarray] = field(default_factory=dict)
    vmax: float = np.inf
    tol: float = IK_TOL
    pair_tol: float = PAIR_TOL

    def reachable(self, pair: bool = False) -> dict[str, np.ndarray]:
        """side -> (F,) bool, the target (pair) reached within tol; invalid targets count as reachable."""
        src, tol = (self.pair_res, self.pair_tol) if pair else (self.wrist_res, self.tol)
        return {s: ~(np.nan_to_num(r, nan=0.0) > tol) for s, r in src.items()}

    def fraction(self, pair: bool = False) -> float:
        """Reachable share of the valid targets over both arms."""
        src, tol = (self.pair_res, self.pair_tol) if pair else (self.wrist_res, self.tol)
        vals = np.concatenate([r[np.isfinite(r)] for r in src.values()])
        return float(np.mean(vals <= tol)) if vals.size else 1.0

    def speed_feasible_fraction(self) -> float | None:
        """Share of frames (both arms) whose IK posture change stays within the joint speed cap."""
        vals = np.concatenate([v[np.isfinite(v)] for v in self.speed.values()]) if self.speed else np.zeros(0)
        return float(np.mean(vals <= self.vmax * (1 + 1e-6))) if vals.size else None


def check_targets(robot: RobotModel, targets: list[TaskTargets], pair: bool = True) -> ReachabilityReport:
    """IK-check every published wrist target (and wrist + elbow pair) of a stream.

    Args:
        robot: reduced model whose arms are checked (waist joints, if any, stay at rest).
        pair: also check the wrist and elbow targets together.
    """
    iks = {s: ArmIk(robot, s) for s in SIDES}
    F = len(targets)
    wres = {s: np.full(F, np.nan) for s in SIDES}
    pres = {s: np.full(F, np.nan) for s in SIDES}
    speed = {s: np.full(F, np.nan) for s in SIDES}
    last = {s: None for s in SIDES}  # (stamp, q) of the previous pair solution
    warm = {s: None for s in SIDES}
    warm_pair = {s: None for s in SIDES}
    for k, tt in enumerate(targets):
        for s in SIDES:
            w = tt.targets.get(f"{s}_wrist")
            if w is None or not w.valid:
                continue
            res, q = iks[s].solve(w.p, q0=warm[s])
            wres[s][k] = res
            warm[s] = q
            e = tt.targets.get(f"{s}_elbow")
            if pair and e is not None and e.valid:
                res, q = iks[s].solve(w.p, e.p, q0=warm_pair[s] if warm_pair[s] is not None else warm[s], tol=PAIR_TOL)
                pres[s][k] = res
                warm_pair[s] = q
                # shoulder and elbow joints only: the wrist joints are free in this IK
                moved = [i for i in iks[s].arm if "wrist" not in robot.joint_names[i]]
                if last[s] is not None and tt.hdr.stamp > last[s][0]:
                    speed[s][k] = np.abs(q[moved] - last[s][1][moved]).max() / (tt.hdr.stamp - last[s][0])
                last[s] = (tt.hdr.stamp, q.copy())
    vmax = float(robot.vmax.min())
    return ReachabilityReport(np.array([tt.hdr.seq for tt in targets]), wres, pres, speed, vmax)
