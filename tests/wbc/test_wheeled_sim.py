"""The balancing TITA-PiPER as a sim core (what `mimic sim --robot models/tita_piper.toml` runs)."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.wbqp_accel import Q_NAMES, WbqpConfig
from services.solver.wbqp_core import WbqpCore, WbqpCoreConfig
from services.wbc.runner import min_jerk
from services.wbc.sim_core import WheeledSimCore
from shared.messages import Header, JointCommand, Target, TaskTargets

pytestmark = pytest.mark.slow


def test_follows_the_planner_and_refuses_bad_commands():
    core = WheeledSimCore("tita_piper")
    planner = WbqpCore(core.wheeled, WbqpCoreConfig(planner=WbqpConfig(dt=0.002)))
    p0 = core.wheeled.kin.hand(planner.q)
    goal = p0 + np.array([0.5, 0.0, 0.0])
    for i in range(2250):  # 4.5 s of 500 Hz commands, two 1 ms physics steps each
        t = i * 0.002
        p, v, _ = min_jerk(p0, goal, 2.5, t)
        msg = TaskTargets(Header(i, t, 0), {"right_wrist": Target(p, np.array([1.0, 0, 0, 0]), v, np.zeros(3))})
        cmd = planner.step(msg if i % 10 == 0 else None, t)
        assert core.apply(JointCommand.decode(cmd.encode()))
        core.step_physics(2)
        assert abs(core.pitch()) < 2e-2  # 13 mrad peak measured: a brisk reach (0.48 m/s^2 torso acceleration)
    st = RobotStateView(core)
    assert st.q[0] > 0.3  # the torso rolled forward
    assert np.linalg.norm(st.hand - goal) < 5e-3  # the simulated hand is at the goal (2.9 mm measured)
    # Bad commands are refused and counted, never applied.
    bad = JointCommand(Header(1, 0.0, 0), "main", "wbqp-accel", list(Q_NAMES), cmd.q.copy(), cmd.qd.copy())
    bad.q[2] = 0.9  # torso 0.9 m high: past the legs' reach
    assert not core.apply(bad) and core.counters.rejects == {"limits": 1}
    bad = JointCommand(Header(1, 0.0, 0), "main", "wbqp-accel", ["j1", "j2"], np.zeros(2), np.zeros(2))
    assert not core.apply(bad) and core.counters.rejects["joint_names"] == 1
    # Commands stop: the watchdog holds, the robot keeps its balance where it is.
    x = core.state().q[0]
    core.step_physics(1000)
    assert core.holding and abs(core.state().q[0] - x) < 5e-3 and abs(core.pitch()) < 2e-3


class RobotStateView:
    """The measured coordinates and hand of a core's RobotState (through the wire format)."""

    def __init__(self, core: WheeledSimCore):
        from shared.messages import RobotState

        st = RobotState.decode(core.state().encode())
        self.q = st.q
        self.hand = st.frames["right_wrist"].p
