"""``SolverCore.tick_holds``: what held each joint's planned velocity on a tick (the eval's goal causes)."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import HOLD_ACCELERATION, HOLD_FREE, HOLD_SPEED, HOLD_STOP, SolverConfig, SolverCore
from services.solver.quintic import RAW_AMAX_FRACTION, RAW_VMAX_FRACTION
from shared.messages import Header, Target, TaskTargets
from shared.mirror import arm_joints
from shared.robot.pinocchio_model import build_robot_model
from shared.rotations import matrix_to_quat

DT = 0.002


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def _targets(robot, left_shift: np.ndarray, seq: int) -> TaskTargets:
    """The rest pose's targets, the left wrist moved by left_shift (3,) [m]."""
    out = {}
    for n, (p, R) in robot.frame_poses(robot.q_rest).items():
        p = p + left_shift if n == "left_wrist" else p
        out[n] = Target(np.asarray(p, float), matrix_to_quat(R), np.zeros(3), np.zeros(3), True, False)
    return TaskTargets(Header(seq, seq * DT), out)


def test_a_far_target_meets_the_acceleration_band_then_the_speed_cap():
    """The left wrist asked 25 cm forward from rest: its joints plan at the acceleration band first (0 -> the raw
    cap takes vmax / a_max, 8 ticks at 7.6 rad/s and 500 rad/s^2), then at their speed cap; the right arm, its
    targets still, is free all along (no waist here: a turning waist would move it too)."""
    robot = build_robot_model(with_waist=False)
    core = SolverCore(robot, SolverConfig())
    core.reset(robot.q_rest)
    left, right = arm_joints(robot, "left"), arm_joints(robot, "right")
    ticks = []
    for k in range(30):
        core.step(_targets(robot, np.array([0.25, 0.0, 0.0]), k), None, k * DT)
        ticks.append(core.tick_holds()[0])
    holds = np.array(ticks)
    assert (holds[1, left] == HOLD_ACCELERATION).any() and not (holds[1, left] == HOLD_SPEED).any()
    assert (holds[15:, left] == HOLD_SPEED).any()
    assert (holds[:, right] == HOLD_FREE).all()
    spinning = np.flatnonzero(holds[-1] == HOLD_SPEED)
    assert np.allclose(np.abs(core.qd_raw[spinning]), RAW_VMAX_FRACTION * robot.vmax[spinning])


def test_the_codes_on_a_box_set_by_hand(robot):
    """Known answers on one tick's box: a joint at its speed cap, one braking to its upper stop 1 cm away, one at
    its acceleration band in mid-range, one inside the box, one fixed in place (lb = ub: held by no single limit)."""
    core = SolverCore(robot, SolverConfig())
    core.reset(robot.q_rest)
    b, n = core.bounds, robot.nq
    vmax = b.vmax
    lb, ub = -vmax.copy(), vmax.copy()
    q = 0.5 * (b.lower + b.upper)
    qd = np.zeros(n)
    a, s, c, f = 0, 1, 2, 3  # joints: acceleration band, speed cap, stop, fixed
    qd[s] = ub[s]
    a_dt = RAW_AMAX_FRACTION * robot.amax[a] * DT
    lb[a], ub[a] = -a_dt, a_dt  # the band around a joint at rest
    qd[a] = -a_dt
    q[c] = b.upper[c] - 0.01
    ub[c] = 0.3  # braking 1 cm before the stop
    qd[c] = 0.3
    lb[f] = ub[f] = qd[f] = 0.2
    core.q_raw[:], core.qd_raw[:], core._box = q, qd, (lb, ub)
    holds, held = core.tick_holds()
    assert holds[[a, s, c, f]].tolist() == [HOLD_ACCELERATION, HOLD_SPEED, HOLD_STOP, HOLD_FREE]
    assert (holds[4:] == HOLD_FREE).all() and not held.any()
