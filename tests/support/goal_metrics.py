"""Hand-made eval metric blocks for the fidelity goals' tests (``services/evaluation/goals.py``)."""

from __future__ import annotations


def errors(mean: float, p99: float) -> dict:
    return {"mean": mean, "p99": p99, "max": 2 * p99}


def hqp_meeting_every_goal(**over) -> dict:
    """An HQP metrics block that meets every goal, with ``over`` replacing entries."""
    m = {
        "wrist_err_cm": errors(0.05, 0.6),
        "elbow_err_cm": errors(0.4, 2.0),
        "wrist_rot_err_deg": errors(2.0, 8.0),
        "stuck_s": 0.0,
        "reachable_fraction": 1.0,
        "limit_violations": 0,
        "acceleration_violations": 0,
        "self_collisions": 0,
        "min_clearance_cm": 1.4,
    }
    return m | over


def peer(wrist: float, elbow: float) -> dict:
    return {"wrist_err_cm": errors(wrist, 1.0), "elbow_err_cm": errors(elbow, 3.0)}
