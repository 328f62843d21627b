"""A solver that starts before the robot state reaches it anchors on the first state that comes.

Under load the ``--startup-wait`` (0.5 s) can pass without a RobotState; the solver
then starts from the rest pose. Without re-anchoring, its commands would pull a
robot standing elsewhere towards the rest pose (2.2 rad away was seen in a
crash/restart run). Here a real ``mimic solve`` process starts with no sim; then
RobotStates of a pose 0.3 rad from rest arrive: its commands must switch to that
pose and stay there while no targets come.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from shared.messages import Header, RobotState
from shared.robot.pinocchio_model import build_robot_model
from tests.support.observer import Observer

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_solver_started_without_state_anchors_on_the_first_state(local_stack):
    robot = build_robot_model()
    q_robot = robot.clip(robot.q_rest + 0.3)
    local_stack.start_router()
    local_stack.start("solver", argv=["mimic", "solve", "--id", "main", "--startup-wait", "0.2"])
    obs = Observer(local_stack.endpoint, local_stack.session)
    try:
        local_stack.wait_alive(["solver/main"], timeout=60)
        obs.wait_until(lambda: len(obs.commands) > 20, 30, "commands from rest")
        with obs.lock:
            from_rest = obs.commands[-1].q
        assert np.max(np.abs(from_rest - robot.q_rest)) < 1e-6  # no state yet: the rest pose
        pub = obs.z.declare_publisher(obs.keys.sim_state)
        t_first = time.monotonic()
        for k in range(30):  # 0.3 s of a robot standing still at q_robot
            msg = RobotState(
                Header(0, 0.0, 0), list(robot.joint_names), q_robot, np.zeros(robot.nq), {}, k * 0.01, "main", True
            )
            pub.put(msg.encode())
            time.sleep(0.01)
        time.sleep(0.2)
        with obs.lock:
            after = [c.q for c in obs.commands if c.t > t_first + 0.1]
        out = local_stack.output(tail=None)
        assert after, out
        assert max(float(np.max(np.abs(q - q_robot))) for q in after) < 1e-6, out
        assert "re-initialised from the first robot state" in out, out
    finally:
        obs.close()
