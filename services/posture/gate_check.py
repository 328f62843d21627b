"""The gate in and out of distribution (``mimic posture gate``): the shipped solver path, JSON figures.

In distribution: a clip's wrist-only targets through :class:`~services.solver.core.SolverCore` with the
policy; the share of ticks whose gate is open. Out of distribution: the same start, then the right
hand is sent where no demonstration went (behind the back, across the body, upside down) and held
there; the gate must close, the arm falls back to the rest-posture pull (over the solver's
``posture_blend_time``, the policy's share of the level ending at 0), and every command stays within the
joint position, velocity and step limits.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from services.evaluation.runner import load_and_retarget, wrist_only_targets
from services.posture.rollout import POSTURE_RETARGET
from services.solver.core import SolverConfig, SolverCore
from shared.messages import Header, TaskTargets
from shared.robot.pinocchio_model import build_robot_model
from shared.rotations import matrix_to_quat, quat_to_matrix

#: The out-of-distribution right-hand target: behind the pelvis, across the body, low [m] (base frame) ...
OOD_POSITION = np.array([-0.22, 0.05, -0.05])
#: ... and turned upside down about the forearm.
OOD_TURN = np.diag([1.0, -1.0, -1.0])


def _run(core: SolverCore, msgs: list[tuple[float, TaskTargets | None]], robot) -> dict:
    """Step the core through (time, message) pairs; gate and safety figures."""
    dt = core.dt
    q_prev = core.q_out.copy()
    open_right, closed_right, violations, max_step = 0, 0, 0, 0.0
    weights: list[float] = []
    statuses: dict[str, int] = {}
    for t, msg in msgs:
        cmd = core.step(msg, None, t)
        g = core.last_gate.get("right")
        if g is not None:
            open_right += int(g)
            closed_right += int(not g)
        w = core.policy_weight.get("right")
        if w is not None:
            weights.append(w)
        violations += int(np.sum((cmd.q < robot.lower - 1e-9) | (cmd.q > robot.upper + 1e-9)))
        violations += int(np.sum(np.abs(cmd.qd) > robot.vmax + 1e-9))
        max_step = max(max_step, float(np.max(np.abs(cmd.q - q_prev) / (robot.vmax * dt))))
        q_prev = cmd.q.copy()
        statuses[cmd.status] = statuses.get(cmd.status, 0) + 1
    n = max(open_right + closed_right, 1)
    return {
        "ticks": len(msgs),
        "right_gate_open_fraction": open_right / n,
        # the policy's share of the right arm's posture level (the gate's hand-over, ``posture_blend_time``):
        # its mean, and at the last tick (0: the rest pull alone)
        "right_policy_weight_mean": float(np.mean(weights)) if weights else None,
        "right_policy_weight_last": weights[-1] if weights else None,
        "limit_violations": violations,
        "max_step_over_vmax_dt": max_step,
        "statuses": statuses,
    }


def gate_report(clip_path: str | Path, policy: str | Path, rate: float = 500.0) -> dict:
    """Gate figures on a clip (in distribution) and on an out-of-distribution hand target."""
    robot = build_robot_model()
    clip, targets = load_and_retarget(Path(clip_path), robot, "bounded", POSTURE_RETARGET)
    fed = wrist_only_targets(targets)
    cfg = SolverConfig(qp="daqp", rate=rate, posture_policy=str(policy), solver_id="gate")
    core = SolverCore(robot, cfg)
    dt = 1.0 / rate
    msgs: list[tuple[float, TaskTargets | None]] = []
    stamps = [tt.hdr.stamp for tt in fed]
    k = 0
    for tick in range(int((stamps[-1] - stamps[0]) / dt)):
        t = stamps[0] + tick * dt
        msg = None
        while k < len(fed) and stamps[k] <= t + 1e-12:
            msg = fed[k]
            k += 1
        msgs.append((t, msg))
    inside = _run(core, msgs, robot)
    inside["policy_ticks"] = core.counts["policy_ticks"]
    # Out of distribution: restart on the clip's first frame, then move the right hand away over 1 s.
    core = SolverCore(robot, cfg)
    first = fed[0]
    wr = first.targets["right_wrist"]
    R_ood = quat_to_matrix(wr.q) @ OOD_TURN
    msgs = []
    t = 0.0
    for tick in range(int(3.0 * rate)):
        t = tick * dt
        a = min(max((t - 0.5) / 1.0, 0.0), 1.0)  # 0.5 s at the start pose, 1 s ramp, then held
        p = (1 - a) * wr.p + a * OOD_POSITION
        R = R_ood if a > 0.5 else quat_to_matrix(wr.q)
        tg = dict(first.targets)
        tg["right_wrist"] = replace(wr, p=p, q=matrix_to_quat(R), v=np.zeros(3), w=np.zeros(3))
        msgs.append((t, TaskTargets(Header(tick + 1, t, 0), tg, first.mode)))
    closed_at = None
    out_of = _run(core, msgs[: int(1.5 * rate)], robot)
    held = _run(core, msgs[int(1.5 * rate) :], robot)
    if core.last_gate.get("right") is False:
        closed_at = "held out-of-distribution target"
    return {
        "clip": clip.name,
        "policy": str(policy),
        "in_distribution": inside,
        "ood_target": {
            "position_m": OOD_POSITION.tolist(),
            "rotation": "clip's first right-hand orientation turned 180 deg about its x axis",
        },
        "ood_ramp": out_of,
        "ood_held": held,
        "gate_closed_on": closed_at,
        "threshold_m": core.policy.threshold.tolist(),
    }
