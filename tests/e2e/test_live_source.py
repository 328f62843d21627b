"""Plugging in a live source as a new user does: the README snippet, verbatim, against a fresh stack."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from services.launcher.stack import REPO_ROOT
from services.retarget.calibration import anthropometric
from shared.messages import Bone, Header, HumanFrame, Pose, RobotState, ServiceStatus

pytestmark = pytest.mark.integration
README = REPO_ROOT / "README.md"


def readme_live_snippet() -> str:
    """The python block of README's "Plugging in a live mocap system" section, as written."""
    text = README.read_text()
    section = text[text.index("### Plugging in a live mocap system") :]
    block = re.search(r"```python\n(.*?)```", section, re.S)
    assert block, "no python snippet in README's live-publisher section"
    return block.group(1)


class _Watch:
    """Right-wrist achieved positions of the sim and the latest retarget status."""

    def __init__(self, stack):
        self.lock = threading.Lock()
        self.wrist: list[tuple[float, np.ndarray]] = []  # (monotonic [s], achieved right wrist (3,) [m])
        self.retarget: ServiceStatus | None = None
        z = stack.bus
        self.subs = [
            z.declare_subscriber(stack.keys.sim_state, self._state),
            z.declare_subscriber(stack.keys.status("retarget"), self._status),
        ]

    def _state(self, s) -> None:
        m = RobotState.decode(s.payload.to_bytes())
        with self.lock:
            self.wrist.append((time.monotonic(), np.asarray(m.frames["right_wrist"].p, float)))

    def _status(self, s) -> None:
        with self.lock:
            self.retarget = ServiceStatus.decode(s.payload.to_bytes())

    def wait_retarget(self, pred, timeout: float = 5.0) -> ServiceStatus | None:
        """The latest retarget status once ``pred(status)`` holds, or the latest after ``timeout`` [s]."""
        deadline = time.monotonic() + timeout
        while True:
            with self.lock:
                st = self.retarget
            if (st is not None and pred(st)) or time.monotonic() >= deadline:
                return st
            time.sleep(0.1)


def _send_wrist_and_elbow_only(pub, seqs: range) -> None:
    """Right wrist + elbow frames (no shoulders, identity rotations) numbered ``seqs``, at 60 Hz."""
    q = np.array([1.0, 0, 0, 0])
    for seq in seqs:
        bones = {
            "right_wrist": Bone(np.array([0.3, -0.25, 0.1]), q),
            "right_elbow": Bone(np.array([0.1, -0.3, 0.2]), q),
        }
        pub.put(HumanFrame(Header(seq, seq / 60, time.time_ns()), "partial", Pose(np.zeros(3), q), bones).encode())
        time.sleep(1 / 60)


def test_readme_live_snippet_moves_the_robot(local_stack):
    """The snippet publishes on $MIMIC_SESSION via $MIMIC_CONNECT; the simulated right wrist follows its lift."""
    local_stack.start_all(["retarget", "solver", "sim"])
    watch = _Watch(local_stack)
    time.sleep(0.5)
    t_start = time.monotonic()
    env = {**os.environ, **local_stack.client_env(), "PYTHONPATH": str(REPO_ROOT)}
    run = subprocess.run(
        [sys.executable, "-c", readme_live_snippet()],
        cwd=REPO_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    time.sleep(0.5)
    with watch.lock:
        samples = [(t, p) for t, p in watch.wrist if t >= t_start]
        status = watch.retarget
    assert samples, f"no robot state during the snippet\n{local_stack.output()}"
    assert status is not None and status.extra.get("calibrated") == 1.0, (status, local_stack.output())
    # The rest second (plus one-arm wait) calibrates; then the forearm lifts forward by up to
    # 0.25 * sin(1.4) ~ 0.25 m: the robot's right wrist must move forward with it, not stand still.
    x = np.array([p[0] for _, p in samples])
    x_rest = float(np.median(x[: max(1, len(x) // 20)]))
    assert x.max() - x_rest > 0.05, f"right wrist x range {x.min():.3f}..{x.max():.3f} m: the robot did not follow"
    assert status.counts.get("published", 0) > 300, status.counts


def test_a_source_without_shoulders_is_told_why_at_once(local_stack, tmp_path):
    """Wrist + elbow only: every frame is rejected and status, log and reason say what is missing."""
    local_stack.start_all(["retarget"])
    watch = _Watch(local_stack)
    q = np.array([1.0, 0, 0, 0])
    pub = local_stack.bus.declare_publisher(local_stack.keys.mocap_frame)
    _send_wrist_and_elbow_only(pub, range(40))
    st = watch.wait_retarget(lambda st: st.rejects.get("uncalibrated", 0) >= 30)
    # Every frame that arrived (the first few may precede the route) was rejected, none retargeted.
    assert st is not None and st.state == "degraded" and st.rejects.get("uncalibrated", 0) >= 30, st
    assert st.counts.get("published", 0) == 0, st
    assert "shoulder" in st.last_error and "mimic calibrate" in st.last_error, st.last_error
    out = local_stack.output()
    assert "rejected, not calibrated" in out and "_shoulder" in out, out
    # The way out the message names: a calibration file installed with `mimic calibrate --file`.
    rest = {"right_shoulder": [0.0, -0.18, 0.45], "right_elbow": [0.0, -0.18, 0.17], "right_wrist": [0.0, -0.18, -0.08]}
    rest.update({k.replace("right", "left"): [p[0], -p[1], p[2]] for k, p in rest.items()})
    full = HumanFrame(
        Header(0, 0.0, 1), "rest", Pose(np.zeros(3), q), {k: Bone(np.array(p), q) for k, p in rest.items()}
    )
    cal_file = tmp_path / "cal.json"
    anthropometric(full).save(cal_file)
    env = {**os.environ, **local_stack.client_env(), "PYTHONPATH": str(REPO_ROOT)}
    cmd = [sys.executable, "-m", "services.cli", "calibrate"]
    shown = subprocess.run(cmd, env=env, cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0 and json.loads(shown.stdout) == {"calibrated": False}, shown
    run = subprocess.run([*cmd, "--file", str(cal_file)], env=env, cwd=REPO_ROOT, capture_output=True, text=True)
    assert run.returncode == 0 and json.loads(run.stdout)["calibrated"] is True, run
    _send_wrist_and_elbow_only(pub, range(40, 60))
    st = watch.wait_retarget(lambda st: st.counts.get("published", 0) >= 20)
    assert st.state == "ok" and st.counts.get("published", 0) >= 20, st
