"""The waist's velocity damped towards zero on level 2 (``SolverConfig.waist_damping_cost``): rows ``cost * qd`` on the
waist joints beside the elbows, for the strict hierarchies only, off by default; on a real clip the waist moves less."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import SolverConfig, SolverCore
from shared.kinematics import Configuration
from tests.support.lockstep import clip_targets_until


def _waist(robot) -> list[int]:
    return [robot.joint_names.index(j) for j in robot.profile.waist]


def test_the_rows_are_the_cost_times_the_waist_velocity_on_level_2(robot17):
    """Whatever the posture, the task's rows are ``A = cost`` on the waist joints' diagonal (0 elsewhere) and
    ``b = 0``: a pull towards zero velocity, not towards a pose; it sits on level 2, below the wrists."""
    core = SolverCore(robot17, SolverConfig(waist_damping_cost=0.2))
    task = core.waist_damping_task
    assert task is not None and task in core.levels[1]
    assert all(task not in lv for lv in (core.levels[0], *core.levels[2:]))
    q = robot17.q_rest.copy()
    q[_waist(robot17)] = [0.4, -0.2, 0.3]  # far from rest: a posture pull would ask for a velocity here
    A, b = np.empty((robot17.nq, robot17.nq)), np.empty(robot17.nq)
    task.fill_qp_objective(Configuration(robot17, q), A, b)
    expected = np.zeros(robot17.nq)
    expected[_waist(robot17)] = 0.2
    np.testing.assert_array_equal(A, np.diag(expected))
    np.testing.assert_array_equal(b, np.zeros(robot17.nq))


def test_off_by_default_and_for_the_weighted_qp(robot17):
    assert SolverCore(robot17, SolverConfig()).waist_damping_task is None
    assert SolverCore(robot17, SolverConfig(algo="wqp", waist_damping_cost=0.2)).waist_damping_task is None
    with pytest.raises(ValueError, match="waist_damping_cost"):
        SolverConfig(waist_damping_cost=-0.1)


def test_the_waist_moves_less_on_a_real_gesture(robot17):
    """bye_normal's first 2.5 s in lock-step, the clip's frames stepping the targets at 30 fps: the waist's speed
    (RMS over ticks and joints) falls by more than 15 % with cost 0.1 (measured 1.57 -> 1.15 rad/s), and the
    wrists' level-1 residual stays small on most ticks (strictness: the rows are below it)."""
    frames = clip_targets_until("dataset-1_bye_normal_001.bvh", robot17, 2.5)
    stamps = np.array([f.hdr.stamp for f in frames]) - frames[0].hdr.stamp
    out = {}
    for cost in (0.0, 0.1):
        core = SolverCore(robot17, SolverConfig(waist_damping_cost=cost))
        core.reset(robot17.q_rest)
        qd, res, j = [], [], 0
        for k in range(int(stamps[-1] * core.config.rate) + 1):
            t = k / core.config.rate
            msg = None
            while j < len(frames) and stamps[j] <= t + 1e-9:
                msg, j = frames[j], j + 1
            cmd = core.step(msg, None, t)
            if t > 0.5:  # after the start-up from rest
                qd.append(cmd.qd[_waist(robot17)])
                res.append(cmd.residuals[0])
        out[cost] = (float(np.sqrt(np.mean(np.square(qd)))), float(np.median(res)))
    assert out[0.1][0] < 0.85 * out[0.0][0], out
    assert out[0.1][1] < 1e-3, out
