"""A restarted sim resumes from its last state, not the rest pose (a 1.88 rad jump was seen)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from services.sim.resume import load_state, save_state, session_state_file
from services.sim.sim_core import SimCore
from shared.messages import RobotState
from shared.paths import REPO_ROOT

pytestmark = pytest.mark.integration


def test_state_file_round_trip_and_bad_files_ignored(tmp_path):
    core = SimCore()
    names = list(core.joint_names)
    q = core.q + 0.1
    save_state(tmp_path / "s.json", names, q)
    assert np.allclose(load_state(tmp_path / "s.json", names), q)
    assert load_state(tmp_path / "absent.json", names) is None
    (tmp_path / "bad.json").write_text('{"joints": ["x"], "q": [1.0]}')
    assert load_state(tmp_path / "bad.json", names) is None  # another robot's file: ignored, not a crash
    core.resume(q)
    assert np.allclose(core.q, np.clip(q, core.lower, core.upper)) and core.holding


def test_a_killed_sim_comes_back_where_the_robot_was(local_stack):
    core = SimCore()
    names = list(core.joint_names)
    q = core.q.copy()
    elbow = names.index(core.robot.profile.arms["right"].elbow)
    q[elbow] = core.lower[elbow] + 0.3 if abs(core.lower[elbow] + 0.3 - q[elbow]) > 0.5 else core.upper[elbow] - 0.3
    state_file = REPO_ROOT / session_state_file(local_stack.session)
    local_stack.start_router()
    save_state(state_file, names, q)  # the last state of a sim that ran before (same stack)
    states: list[tuple[float, np.ndarray]] = []
    lock = threading.Lock()

    def on_state(s) -> None:
        m = RobotState.decode(s.payload.to_bytes())
        with lock:
            states.append((time.monotonic(), np.asarray(m.q)))

    sub = local_stack.bus.declare_subscriber(local_stack.keys.sim_state, on_state)
    try:
        local_stack.start_all(["sim"])
        time.sleep(1.0)
        with lock:
            first = states[0][1]
        assert abs(first[elbow] - q[elbow]) < 0.02, (first[elbow], q[elbow])  # not the rest pose
        local_stack.kill9("sim")
        with lock:
            last_before, n = states[-1][1], len(states)
        t = local_stack.start("sim")
        local_stack.wait_alive(["sim"])
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and len(states) == n:
            time.sleep(0.05)
        with lock:
            after = [s for tt, s in states[n:] if tt >= t]
        assert after, "no state from the restarted sim"
        assert np.max(np.abs(after[0] - last_before)) < 0.02, np.max(np.abs(after[0] - last_before))
    finally:
        sub.undeclare()
    local_stack.close()
    assert not state_file.exists(), "the stack's end must forget the sim state"
