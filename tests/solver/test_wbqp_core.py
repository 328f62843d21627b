"""wbqp-accel behind the command contract: TaskTargets in, JointCommands (7-D q) out, over the wire format."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.wbqp_accel import Q_NAMES, WbqpConfig
from services.solver.wbqp_core import WbqpCore, WbqpCoreConfig
from services.wbc.runner import min_jerk
from shared.messages import Header, JointCommand, Target, TaskTargets
from shared.robot.wheeled import build_wheeled_robot, planner_limits

DT = 0.002


@pytest.fixture(scope="module")
def robot():
    return build_wheeled_robot("tita_piper")


def targets(seq: int, p: np.ndarray, v: np.ndarray | None = None, valid: bool = True) -> TaskTargets:
    tg = Target(np.asarray(p, float), np.array([1.0, 0, 0, 0]), np.zeros(3) if v is None else v, np.zeros(3), valid)
    return TaskTargets(Header(seq, seq * 0.01, 0), {"right_wrist": tg})


def test_reaching_forward_rolls_the_torso_forward(robot):
    core = WbqpCore(robot, WbqpCoreConfig(planner=WbqpConfig(dt=DT)))
    assert core.step(None, 0.0).status == "init"
    p0 = robot.kin.hand(core.q)
    goal = p0 + np.array([1.0, 0.0, 0.0])  # 1 m ahead: beyond the arm alone
    lo, hi = planner_limits(robot)
    cmd = None
    for i in range(1, 2500):
        t = i * DT
        # Targets at 100 Hz on a smooth 2 s reach, as a retargeter would send them.
        msg = None
        if i % 5 == 0:
            p, v, _ = min_jerk(p0, goal, 2.0, t)
            msg = targets(i, p, v)
        cmd = JointCommand.decode(core.step(msg, t).encode())  # through the wire format
        assert cmd.joints == list(Q_NAMES)
        assert np.all(cmd.q >= lo - 1e-9) and np.all(cmd.q <= hi + 1e-9)
        assert cmd.status in (("init",) if i < 5 else ("ok", "infeasible")), cmd.reason
    assert cmd.q[0] > 0.5  # the torso carried the hand most of the way
    assert np.linalg.norm(robot.kin.hand(cmd.q) - goal) < 2e-3
    assert cmd.residuals[0] < 1e-4


def test_stale_and_invalid_targets_are_held(robot):
    core = WbqpCore(robot, WbqpCoreConfig(planner=WbqpConfig(dt=DT), timeout=0.1))
    p0 = robot.kin.hand(core.q)
    core.step(targets(1, p0 + np.array([0.05, 0.0, 0.0])), 0.0)
    cmd = core.step(None, 0.2)
    assert cmd.status == "held" and "stale" in cmd.reason
    cmd = core.step(targets(2, p0, valid=False), 0.21)
    assert cmd.status == "held" and "invalid" in cmd.reason
