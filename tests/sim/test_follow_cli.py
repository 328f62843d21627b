"""The local solver swap: start a second solver beside the stack, `mimic follow` it, the sim follows."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from shared.messages import RobotState
from shared.paths import REPO_ROOT

pytestmark = pytest.mark.integration


def _follow(stack, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "follow", *argv],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **stack.client_env(), "PYTHONPATH": str(REPO_ROOT)},
    )


def test_follow_switches_the_sim_to_a_live_solver_and_refuses_a_missing_one(local_stack):
    local_stack.start_all(["solver", "sim"])
    local_stack.start("b", argv=["mimic", "solve", "--algo", "wqp", "--id", "b"])
    local_stack.wait_alive(["solver/b"])
    followed: list[str] = []
    sub = local_stack.bus.declare_subscriber(
        local_stack.keys.sim_state, lambda s: followed.append(RobotState.decode(s.payload.to_bytes()).solver_id)
    )
    try:
        missing = _follow(local_stack, "nobody")
        assert missing.returncode == 1
        err = [ln for ln in missing.stderr.splitlines() if " E " in ln]
        assert len(err) == 1 and "no solver 'nobody' is alive" in err[0] and "b, main" in err[0], missing.stderr
        shown = _follow(local_stack)
        assert shown.returncode == 0 and json.loads(shown.stdout)["follow"] == "main", shown
        swap = _follow(local_stack, "b")
        assert swap.returncode == 0, swap.stderr
        assert json.loads(swap.stdout) == {"follow": "b", "was": "main", "solvers_alive": ["b", "main"]}
        t = time.monotonic()
        n = len(followed)
        while time.monotonic() - t < 5 and "b" not in followed[n:]:
            time.sleep(0.05)
        assert "b" in followed[n:], "the sim's states do not name the new solver"
    finally:
        sub.undeclare()
