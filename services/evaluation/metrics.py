"""Metrics of an evaluation trace: the numbers of the paper's section 4.3, and more."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from services.evaluation.reachability import ReachabilityReport
from services.evaluation.runner import Trace
from shared.messages import TaskTargets
from shared.robot.pinocchio_model import RobotModel
from shared.rotations import quat_to_matrix
from shared.targets import ELBOWS, WRISTS

#: Level-1 residual under which the strict hierarchy counts a wrist target as met.
REACHABLE_TOL = 1e-3
#: Per-clip counts the summary adds up (and gives as integers).
SUMMED = (
    "limit_violations",
    "acceleration_violations",
    "self_collisions",
    "qp_fallbacks",
    "recoveries",
    "surface_ticks",
)
#: Wrist error [m] above which a tick on a reachable target counts towards ``stuck_s``.
STUCK_ERR = 0.02
#: How far [cm] the HQP's elbow mean may be above another algorithm's and still count as not worse (issue 12).
ELBOW_TIE_CM = 0.05


def _stats(v: np.ndarray) -> dict:
    v = np.asarray(v, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"mean": None, "p99": None, "max": None}
    return {"mean": float(v.mean()), "p99": float(np.percentile(v, 99)), "max": float(v.max())}


def target_adjustment(plain: list, published: list) -> dict:
    """How far the published targets moved from the plain retargeted ones (``consistent_targets``,
    ``wrist_range``, ``trunk_clearance``).

    Args:
        plain, published: TaskTargets of the same clip frames without and with the option (same seqs).

    Returns:
        ``wrist_cm``, ``elbow_cm`` and ``wrist_rot_deg``: mean / p99 / max over the frames and arms whose wrist
        and elbow are valid in both; ``arm_frames`` compared (frames x arms).
    """
    by_seq = {tt.hdr.seq: tt for tt in plain}
    wrist, elbow, rot = [], [], []
    for tt in published:
        ref = by_seq.get(tt.hdr.seq)
        if ref is None:
            continue
        for w, e in zip(WRISTS, ELBOWS, strict=True):
            a, b = tt.targets[w], ref.targets[w]
            ea, eb = tt.targets[e], ref.targets[e]
            if not (a.valid and b.valid and ea.valid and eb.valid):
                continue
            wrist.append(100.0 * float(np.linalg.norm(a.p - b.p)))
            elbow.append(100.0 * float(np.linalg.norm(ea.p - eb.p)))
            rot.append(np.degrees(np.linalg.norm(pin.log3(quat_to_matrix(a.q) @ quat_to_matrix(b.q).T))))
    return {
        "wrist_cm": _stats(np.array(wrist)),
        "elbow_cm": _stats(np.array(elbow)),
        "wrist_rot_deg": _stats(np.array(rot)),
        "arm_frames": len(elbow),
    }


def operator_errors(trace: Trace, plain: list) -> dict:
    """The robot at each frame's instant against that frame's *plain* retargeted targets [cm, deg].

    With ``consistent_targets`` the solver tracks targets moved towards what the arm can do, and every other
    error block is measured against those; these are measured against the targets the operator's motion
    gave before that move (as :func:`frame_errors`: the command of the tick before the frame's arrival tick).

    Args:
        plain: TaskTargets of the clip without the option (matched to the trace's frames by seq).

    Returns:
        ``wrist_err_cm_vs_operator``, ``elbow_err_cm_vs_operator``, ``wrist_rot_err_deg_vs_operator``.
    """
    by_seq = {tt.hdr.seq: tt for tt in plain}
    pos: dict[str, list[float]] = {"wrist": [], "elbow": []}
    rot: list[float] = []
    for tick, seq in zip(trace.frame_tick, trace.frame_seq, strict=True):
        ref = by_seq.get(int(seq))
        if ref is None or tick < 1:
            continue
        for n, tg in ref.targets.items():
            if not tg.valid or n not in trace.kin_p:
                continue
            pos["wrist" if n in WRISTS else "elbow"].append(
                100.0 * float(np.linalg.norm(trace.kin_p[n][tick - 1] - tg.p))
            )
            if n in WRISTS and n in trace.kin_R and tg.use_rotation:
                rot.append(np.degrees(np.linalg.norm(pin.log3(quat_to_matrix(tg.q).T @ trace.kin_R[n][tick - 1]))))
    return {
        "wrist_err_cm_vs_operator": _stats(np.array(pos["wrist"])),
        "elbow_err_cm_vs_operator": _stats(np.array(pos["elbow"])),
        "wrist_rot_err_deg_vs_operator": _stats(np.array(rot)),
    }


def per_tick(trace: Trace, report: ReachabilityReport, per_frame: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """side -> (K,) bool: a per-frame flag of the report (side -> (F,) bool) on each tick, from the frame the tick
    tracks (False on ticks tracking a frame the report did not check)."""
    index = {int(s): k for k, s in enumerate(report.seq)}
    rows = np.array([index.get(int(s), -1) for s in trace.seq])
    return {side: np.where(rows >= 0, v[np.maximum(rows, 0)], False) for side, v in per_frame.items()}


def tick_reachable(trace: Trace, report: ReachabilityReport) -> dict[str, np.ndarray]:
    """side -> (K,) bool: the wrist target the tick tracks (its frame's) passed the IK check."""
    return per_tick(trace, report, report.reachable())


def tick_inside(trace: Trace, report: ReachabilityReport) -> dict[str, np.ndarray]:
    """side -> (K,) bool: the wrist target the tick tracks (its frame's) puts the hand inside the body."""
    return per_tick(trace, report, report.inside())


def longest_run(flags: np.ndarray) -> int:
    """Length of the longest run of True in a (K,) bool array."""
    best = run = 0
    for f in np.asarray(flags, dtype=bool):
        run = run + 1 if f else 0
        best = max(best, run)
    return best


def stuck_seconds(trace: Trace, reachable: dict[str, np.ndarray], err: float = STUCK_ERR) -> float:
    """Longest interval [s] with a wrist more than ``err`` [m] off a reachable (IK-checked) target."""
    worst = 0
    for w in WRISTS:
        if w not in trace.kin_p:
            continue
        side = w.split("_")[0]
        e = np.linalg.norm(trace.kin_p[w] - trace.ref_p[w], axis=1)
        bad = (e > err) & trace.ref_ok[w] & reachable.get(side, np.ones(len(e), bool))
        worst = max(worst, longest_run(bad))
    return float(worst * trace.dt)


def jerk_rms(trace: Trace) -> float | None:
    """RMS over ticks and joints of the commanded joints' third derivative [rad/s^3]."""
    if len(trace.q) < 4:
        return None
    j = np.diff(trace.q, n=3, axis=0) / trace.dt**3
    return float(np.sqrt(np.mean(j * j)))


def waist_speed_rms(trace: Trace, robot: RobotModel) -> float | None:
    """RMS over ticks and waist joints of the commanded waist velocity [rad/s] (None without a waist): how much the
    torso moves, which the operator's barely does in a gesture (``SolverConfig.waist_damping_cost``)."""
    idx = [robot.joint_names.index(j) for j in robot.profile.waist if j in robot.joint_names]
    if not idx or not len(trace.qd):
        return None
    return float(np.sqrt(np.mean(trace.qd[:, idx] ** 2)))


def position_errors(ref: dict, got: dict, ok: dict, names, mask: np.ndarray | None = None) -> np.ndarray:
    """Euclidean errors [m] over ticks and targets where the reference is valid (and ``mask``)."""
    out = []
    for n in names:
        if n not in got or n not in ref:
            continue
        sel = ok[n] if mask is None else ok[n] & mask
        out.append(np.linalg.norm(got[n][sel] - ref[n][sel], axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def rotation_errors(ref: dict, got: dict, ok: dict, mask: np.ndarray | None = None) -> np.ndarray:
    """Geodesic angle [deg] between reference and achieved wrist orientations."""
    out = []
    for n in WRISTS:
        if n not in got or n not in ref:
            continue
        sel = ok[n] if mask is None else ok[n] & mask
        Rr, Rg = ref[n][sel], got[n][sel]
        tr = np.einsum("kij,kij->k", Rr, Rg)  # trace(Rr^T Rg)
        out.append(np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))))
    return np.concatenate(out) if out else np.zeros(0)


def rotation_ok(trace: Trace) -> dict[str, np.ndarray]:
    """Wrist -> (K,) ticks whose reference is valid and carries an orientation (none for a source without
    measured orientations: its wrists have no rotation error to score)."""
    return {n: ok & trace.ref_rot[n] if n in trace.ref_rot else ok for n, ok in trace.ref_ok.items()}


def frame_errors(trace: Trace, names) -> np.ndarray:
    """Errors [m] of the robot at each frame's own instant against that frame's target.

    The command of the tick before a frame's arrival tick is the pose for the arrival instant (each
    command is for t + dt), and the frame's stamp lies within that tick: robot and operator at the
    same time, without the extrapolation the tick errors are measured against. So this does not
    depend on how the pipeline predicts between frames (velocity filter, horizon): the lag a viewer
    sees between the operator's frames and the robot shows here.
    """
    out = []
    idx = trace.frame_tick - 1
    keep = idx >= 0
    for n in names:
        if n not in trace.frame_p or n not in trace.kin_p or not len(idx):
            continue
        sel = keep & trace.frame_ok[n]
        out.append(np.linalg.norm(trace.kin_p[n][idx[sel]] - trace.frame_p[n][sel], axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def frame_rotation_errors(trace: Trace) -> np.ndarray:
    """Geodesic angles [deg] of the robot's wrists at each frame's own instant against that frame's orientation
    (as :func:`frame_errors` for positions: what the operator's hand and the robot's showed at the same time,
    whatever the pipeline predicted between frames)."""
    idx = trace.frame_tick - 1
    keep = idx >= 0
    ref, got, ok = {}, {}, {}
    for n in WRISTS:
        if n in trace.frame_R and n in trace.kin_R and len(idx):
            ref[n], got[n], ok[n] = trace.frame_R[n][keep], trace.kin_R[n][idx[keep]], trace.frame_rot[n][keep]
    return rotation_errors(ref, got, ok)


def limit_violations(trace: Trace, robot: RobotModel, tol: float = 1e-9) -> int:
    """Count of (tick, joint) pairs outside the position or velocity limits."""
    pos = (trace.q < robot.lower - tol) | (trace.q > robot.upper + tol)
    vel = np.abs(trace.qd) > robot.vmax + 1e-6
    return int(pos.sum() + vel.sum())


def acceleration_violations(trace: Trace, robot: RobotModel, rel_tol: float = 1e-6) -> int:
    """Count of (tick, joint) pairs whose commanded velocity changed by more than ``a_max dt`` since the tick before.

    ``limit_violations`` counts positions and velocities only; a command may meet both and still ask a motor
    for more acceleration than it has (``RobotModel.amax``, the limit our solvers plan within).
    """
    if len(trace.t) < 2:
        return 0
    dqd = np.abs(np.diff(trace.qd, axis=0))
    step = robot.amax[None, :] * np.diff(trace.t)[:, None]
    return int(np.sum(dqd > step * (1.0 + rel_tol) + 1e-9))


def published_waist(targets: list[TaskTargets]) -> np.ndarray | None:
    """(N, w) [rad] the operator's torso as waist angles that each published frame carried (``TaskTargets.waist``,
    the retargeter's :mod:`services.retarget.torso`: what ``SolverConfig.waist_follow_cost`` follows), row = frame
    seq, NaN rows for seqs without one; None when no frame carried one (no measured chest: C3D, wrist-only)."""
    rows = {tt.hdr.seq: tt.waist for tt in targets if len(tt.waist)}
    if not rows:
        return None
    out = np.full((max(tt.hdr.seq for tt in targets) + 1, len(next(iter(rows.values())))), np.nan)
    for seq, w in rows.items():
        out[seq] = w
    return out


def has_waist(robot: RobotModel) -> bool:
    """The model controls every waist joint of its profile (not with ``mimic eval --no-waist``)."""
    return bool(robot.profile.waist) and all(j in robot.joint_names for j in robot.profile.waist)


def waist_vs_operator(trace: Trace, robot: RobotModel, operator: np.ndarray) -> dict:
    """``waist_vs_operator_deg``: per tick, the largest difference [deg] between the robot's waist joints and the
    operator's torso as waist angles in the frame the tick tracked (``trace.seq``); ticks before the first frame or
    of frames without them are left out.

    Args:
        operator: (N, w) [rad] the operator's waist angles per frame seq, NaN rows without (:func:`published_waist`).
    """
    seq = np.asarray(trace.seq, dtype=int)
    ok = (seq >= 0) & (seq < len(operator))
    waist_q = np.asarray(trace.q)[ok][:, robot.indices(robot.profile.waist)]
    d = np.degrees(np.abs(waist_q - operator[seq[ok]])).max(axis=1)
    return {"waist_vs_operator_deg": _stats(d)}


def operator_waist_turn(operator: np.ndarray, robot: RobotModel) -> dict:
    """``operator_waist_deg``: per frame with them, the largest departure [deg] of the operator's waist angles
    (N, w) [rad] from the robot's waist rest: how far the operator's own torso turned, the scale of
    ``waist_vs_operator_deg``."""
    return _stats(np.degrees(np.abs(operator - robot.q_rest[robot.indices(robot.profile.waist)])).max(axis=1))


def reachable_mask(reference: Trace) -> np.ndarray:
    """Ticks where the strict hierarchy met the wrist level."""
    return np.nan_to_num(reference.res1, nan=np.inf) < REACHABLE_TOL


def trace_metrics(
    trace: Trace,
    robot: RobotModel,
    reachable: np.ndarray | None = None,
    report: ReachabilityReport | None = None,
    sim: bool = False,
) -> dict:
    """The metrics dict ``M`` of the eval JSON for one algorithm on one clip (errors in cm).

    Args:
        reachable: (K,) bool, ticks where the strict hierarchy met level 1 (``level1_met_fraction``).
        report: IK check of the published targets: ``reachable_fraction`` (wrists), ``pair_reachable_fraction``
            (wrist with its elbow), ``stuck_s`` and the ``*_reachable`` blocks are measured against it.
        sim: the trace has a simulated run (``self_collisions`` count its penetrating ticks).
    """
    cm = 100.0
    m = {
        "wrist_err_cm": _stats(cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, WRISTS)),
        "elbow_err_cm": _stats(cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, ELBOWS)),
        "wrist_err_cm_sim": _stats(cm * position_errors(trace.ref_p, trace.sim_p, trace.ref_ok, WRISTS)),
        "elbow_err_cm_sim": _stats(cm * position_errors(trace.ref_p, trace.sim_p, trace.ref_ok, ELBOWS)),
        "wrist_rot_err_deg": _stats(rotation_errors(trace.ref_R, trace.kin_R, rotation_ok(trace))),
        "wrist_rot_err_deg_sim": _stats(rotation_errors(trace.ref_R, trace.sim_R, rotation_ok(trace))),
        "wrist_rot_frame_err_deg": _stats(frame_rotation_errors(trace)),
        "wrist_frame_err_cm": _stats(cm * frame_errors(trace, WRISTS)),
        "elbow_frame_err_cm": _stats(cm * frame_errors(trace, ELBOWS)),
        "solve_ms": {
            "mean": float(trace.solve_ms.mean()),
            "p50": float(np.percentile(trace.solve_ms, 50)),
            "p99": float(np.percentile(trace.solve_ms, 99)),
        },
        "limit_violations": limit_violations(trace, robot),
        "acceleration_violations": acceleration_violations(trace, robot),
        "ticks": len(trace.t),
        "status_counts": {s: int(c) for s, c in zip(*np.unique(trace.status, return_counts=True))},
        "qp_fallbacks": int(trace.counts.get("qp_fallbacks", 0)),
    }
    m["jerk_rms"] = jerk_rms(trace)
    m["waist_speed_rms"] = waist_speed_rms(trace, robot)
    if trace.clearance is not None:
        m["self_collisions"] = int(np.sum(trace.collide))
        m["self_collision_source"] = "sim contacts" if sim else "kinematic clearance < 0"
        c = trace.clearance[np.isfinite(trace.clearance)]
        m["min_clearance_cm"] = float(cm * c.min()) if c.size else None
    if trace.counts.get("surface_ticks"):  # ticks the solver moved a wrist target onto the trunk's surface
        m["surface_ticks"] = int(trace.counts["surface_ticks"])
    if trace.counts.get("recoveries"):  # lock-up recoveries the solver started (SolverConfig.recovery)
        m["recoveries"] = int(trace.counts["recoveries"])
    ticks = trace.counts.get("policy_ticks", 0)
    if ticks:  # a posture policy ran: how often its gate sent an arm to the rest posture instead
        m["policy_ticks"] = int(ticks)
        m["gate_closed_fraction"] = trace.counts.get("gate_closed", 0) / (2.0 * ticks)
    if trace.policy_p:  # an elbow-kind policy aimed elbow tasks: its prediction's error, and the robot's from it
        aimed = {n: trace.ref_ok[n] & np.isfinite(p).all(axis=1) for n, p in trace.policy_p.items()}
        m["policy_elbow_err_cm"] = _stats(cm * position_errors(trace.ref_p, trace.policy_p, aimed, ELBOWS))
        m["elbow_vs_policy_cm"] = _stats(cm * position_errors(trace.policy_p, trace.kin_p, aimed, ELBOWS))
    if reachable is not None and len(reachable) == len(trace.t):
        m["level1_met_fraction"] = float(reachable.mean())
        m["reachable_fraction"] = float(reachable.mean())
        mask = reachable
    if report is not None:
        per_side = tick_reachable(trace, report)
        mask = per_side["left"] & per_side["right"]
        m["reachable_fraction"] = report.fraction()
        m["pair_reachable_fraction"] = report.fraction(pair=True)
        m["speed_feasible_fraction"] = report.speed_feasible_fraction()
        m["stuck_s"] = stuck_seconds(trace, per_side)
        if report.body_dist:  # published frames, and the ticks tracking one, whose wrist target is inside the body
            inside = tick_inside(trace, report)
            m["targets_in_body"] = report.in_body() | {"ticks_inside": int(np.sum(inside["left"] | inside["right"]))}
    if reachable is not None or report is not None:
        m["wrist_err_cm_reachable"] = _stats(cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, WRISTS, mask))
        m["elbow_err_cm_reachable"] = _stats(cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, ELBOWS, mask))
    return m


def compare(entry: dict, reference: str) -> dict:
    """Per clip: ``reference`` (the HQP) beside every other algorithm, on the error means and p99s [cm, deg], and
    whether its elbow mean is at most :data:`ELBOW_TIE_CM` above the other's and its wrist mean below."""
    ref = entry["algos"].get(reference)
    out: dict = {}
    if ref is None:
        return out
    keys = ("wrist_err_cm", "elbow_err_cm", "wrist_rot_err_deg")
    for algo, m in entry["algos"].items():
        if algo == reference:
            continue
        row = {}
        for k in keys:
            for stat in ("mean", "p99"):
                a, b = ref[k].get(stat), m[k].get(stat)
                row[f"{k}_{stat}"] = {reference: a, algo: b}
        e_ref, e_alg = ref["elbow_err_cm"]["mean"], m["elbow_err_cm"]["mean"]
        row["hqp_elbow_better"] = bool(e_ref is not None and e_alg is not None and e_ref <= e_alg + ELBOW_TIE_CM)
        w_ref, w_alg = ref["wrist_err_cm"]["mean"], m["wrist_err_cm"]["mean"]
        row["hqp_wrist_better"] = bool(w_ref is not None and w_alg is not None and w_ref < w_alg)
        out[algo] = row
    return out


def summarise(per_clip: list[dict]) -> dict:
    """Summary over clips: frame-weighted means, maxima of maxima, pooled solve-time figures."""
    out: dict = {}
    algos = sorted({a for c in per_clip for a in c["algos"]})
    for a in algos:
        ms = [(c["algos"][a], c["frames"]) for c in per_clip if a in c["algos"]]
        s: dict = {}
        # every key any clip has, over the clips that have it (``recoveries`` only where the solver started one)
        for key in dict.fromkeys(k for m, _ in ms for k in m):
            have = [(m[key], w) for m, w in ms if key in m]
            vals = [v for v, _ in have]
            if isinstance(vals[0], dict) and "max" in vals[0]:
                means = [(v["mean"], w) for v, w in have if v.get("mean") is not None]
                maxes = [v["max"] for v in vals if v.get("max") is not None]
                p99s = [v["p99"] for v in vals if v.get("p99") is not None]
                s[key] = {
                    "mean": float(np.average([x for x, _ in means], weights=[w for _, w in means])) if means else None,
                    # the worst clip's p99: the goals hold per clip
                    "p99": float(max(p99s)) if p99s else None,
                    "max": float(max(maxes)) if maxes else None,
                }
            elif key == "solve_ms":
                s[key] = {k: float(np.mean([v[k] for v in vals])) for k in ("mean", "p50", "p99")}
            elif isinstance(vals[0], int | float) and not isinstance(vals[0], bool):
                numbered = [(v, w) for v, w in have if isinstance(v, int | float)]
                nums = [v for v, _ in numbered]
                if key in SUMMED or key == "ticks":
                    s[key] = float(np.sum(nums))
                elif key in ("stuck_s",):
                    s[key] = float(np.max(nums))
                elif key == "min_clearance_cm":
                    s[key] = float(np.min(nums))
                elif key.endswith("reachable_fraction"):
                    s[key] = float(np.min(nums))  # the worst clip: the goal holds per clip
                    s[f"{key}_mean"] = float(np.average(nums, weights=[w for _, w in numbered]))
                else:
                    s[key] = float(np.mean(nums))
        s["limit_violations"] = int(s.get("limit_violations", 0))
        for key in SUMMED:
            if key in s:
                s[key] = int(s[key])
        out[a] = s
    return out
