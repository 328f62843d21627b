"""Metrics of an evaluation trace: the numbers of the paper's section 4.3, and more."""

from __future__ import annotations

import numpy as np

from services.evaluation.runner import Trace
from shared.robot.pinocchio_model import RobotModel
from shared.targets import ELBOWS, WRISTS

#: Level-1 residual under which the strict hierarchy counts a wrist target as met.
REACHABLE_TOL = 1e-3


def _stats(v: np.ndarray) -> dict:
    v = np.asarray(v, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"mean": None, "max": None}
    return {"mean": float(v.mean()), "max": float(v.max())}


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


def limit_violations(trace: Trace, robot: RobotModel, tol: float = 1e-9) -> int:
    """Count of (tick, joint) pairs outside the position or velocity limits."""
    pos = (trace.q < robot.lower - tol) | (trace.q > robot.upper + tol)
    vel = np.abs(trace.qd) > robot.vmax + 1e-6
    return int(pos.sum() + vel.sum())


def reachable_mask(reference: Trace) -> np.ndarray:
    """Ticks where the strict hierarchy met the wrist level."""
    return np.nan_to_num(reference.res1, nan=np.inf) < REACHABLE_TOL


def trace_metrics(trace: Trace, robot: RobotModel, reachable: np.ndarray | None = None) -> dict:
    """The metrics dict ``M`` of the eval JSON for one algorithm on one clip (errors in cm)."""
    cm = 100.0
    m = {
        "wrist_err_cm": _stats(cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, WRISTS)),
        "elbow_err_cm": _stats(cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, ELBOWS)),
        "wrist_err_cm_sim": _stats(cm * position_errors(trace.ref_p, trace.sim_p, trace.ref_ok, WRISTS)),
        "elbow_err_cm_sim": _stats(cm * position_errors(trace.ref_p, trace.sim_p, trace.ref_ok, ELBOWS)),
        "wrist_rot_err_deg": _stats(rotation_errors(trace.ref_R, trace.kin_R, trace.ref_ok)),
        "solve_ms": {
            "mean": float(trace.solve_ms.mean()),
            "p50": float(np.percentile(trace.solve_ms, 50)),
            "p99": float(np.percentile(trace.solve_ms, 99)),
        },
        "limit_violations": limit_violations(trace, robot),
        "ticks": len(trace.t),
        "status_counts": {s: int(c) for s, c in zip(*np.unique(trace.status, return_counts=True))},
    }
    if reachable is not None and len(reachable) == len(trace.t):
        m["reachable_fraction"] = float(reachable.mean())
        m["wrist_err_cm_reachable"] = _stats(
            cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, WRISTS, reachable)
        )
        m["elbow_err_cm_reachable"] = _stats(
            cm * position_errors(trace.ref_p, trace.kin_p, trace.ref_ok, ELBOWS, reachable)
        )
    return m


def summarise(per_clip: list[dict]) -> dict:
    """Summary over clips: frame-weighted means, maxima of maxima, pooled solve-time figures."""
    out: dict = {}
    algos = sorted({a for c in per_clip for a in c["algos"]})
    for a in algos:
        ms = [(c["algos"][a], c["frames"]) for c in per_clip if a in c["algos"]]
        s: dict = {}
        for key in ms[0][0]:
            vals = [m[key] for m, _ in ms]
            if isinstance(vals[0], dict) and "max" in vals[0]:
                means = [(v["mean"], w) for v, (_, w) in zip(vals, ms) if v.get("mean") is not None]
                maxes = [v["max"] for v in vals if v.get("max") is not None]
                s[key] = {
                    "mean": float(np.average([x for x, _ in means], weights=[w for _, w in means])) if means else None,
                    "max": float(max(maxes)) if maxes else None,
                }
            elif key == "solve_ms":
                s[key] = {k: float(np.mean([v[k] for v in vals])) for k in ("mean", "p50", "p99")}
            elif isinstance(vals[0], int | float):
                s[key] = float(np.sum(vals)) if key in ("limit_violations", "ticks") else float(np.mean(vals))
        s["limit_violations"] = int(s.get("limit_violations", 0))
        out[a] = s
    return out
