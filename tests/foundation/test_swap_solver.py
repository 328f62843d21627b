"""`mimic swap-solver`: a running `mimic up` replaces its solver in one step, and says so."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest

from services.sim.follow_cli import alive_solvers
from shared.bus import bus_args, free_port, open_session
from shared.keys import Keys
from shared.messages import RobotState
from shared.paths import REPO_ROOT

pytestmark = pytest.mark.integration


def _mimic(env: dict, *argv: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", *argv],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **env, "PYTHONPATH": str(REPO_ROOT)},
    )


def readme_swap_command() -> str:
    """The bash block of README's local solver swap (one line: mimic swap-solver)."""
    text = (REPO_ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text[text.index("one command replaces the running solver") :], re.S)
    assert block and "swap-solver" in block.group(1), "no swap-solver command in README's local swap"
    return block.group(1)


def _errors(run: subprocess.CompletedProcess) -> list[str]:
    return [ln for ln in (run.stdout + run.stderr).splitlines() if " E " in ln or "Traceback" in ln]


def test_swap_solver_without_a_stack_says_so_in_one_line():
    env = {"MIMIC_SESSION": f"noswap{free_port()}", "MIMIC_CONNECT": f"tcp/127.0.0.1:{free_port()}"}
    run = _mimic(env, "swap-solver", "--algo", "wqp", timeout=60)
    assert run.returncode == 1
    errors = _errors(run)
    assert len(errors) == 1 and "no mimic up answered" in errors[0] and "mimic follow" in errors[0], run.stderr


def test_swap_solver_replaces_the_running_solver_of_mimic_up(tmp_path):
    session, endpoint = f"swap{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    env = {"MIMIC_SESSION": session, "MIMIC_CONNECT": endpoint}
    out = tmp_path / "up.log"
    with out.open("w") as fh:
        argv = ["up", "--session", session, "--endpoint", endpoint, "--only", "solver", "--only", "sim"]
        up = subprocess.Popen(
            [sys.executable, "-m", "services.cli", *argv, "--summary", str(tmp_path / "s.json")],
            cwd=REPO_ROOT,
            stdout=fh,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
        )
    try:
        deadline = time.monotonic() + 120
        while "stack up on session" not in out.read_text():
            assert up.poll() is None and time.monotonic() < deadline, out.read_text()[-3000:]
            time.sleep(0.2)
        shown = _mimic(env, "swap-solver")
        assert shown.returncode == 0, shown.stderr
        assert json.loads(shown.stdout) == {"follow": "main", "solvers": {"main": "hqp-nullspace"}}

        bad = _mimic(env, "swap-solver", "--algo", "bogus")
        assert bad.returncode == 1 and len(_errors(bad)) == 1 and "unknown algorithm 'bogus'" in bad.stderr

        with open_session(bus_args(connect=[endpoint], session=session)) as z:
            keys = Keys(session)
            followed: list[str] = []
            sub = z.declare_subscriber(
                keys.sim_state, lambda s: followed.append(RobotState.decode(s.payload.to_bytes()).solver_id)
            )
            swap = subprocess.run(  # README's command, verbatim
                readme_swap_command(),
                shell=True,
                cwd=REPO_ROOT,
                capture_output=True,
                text=True,
                timeout=120,
                env={**os.environ, **env},
            )
            assert swap.returncode == 0, swap.stderr
            assert json.loads(swap.stdout) == {"follow": "wqp", "was": "main", "algo": "wqp", "stopped": True}
            n = len(followed)
            t = time.monotonic()
            while "wqp" not in followed[n:] and time.monotonic() - t < 10:
                time.sleep(0.05)
            assert "wqp" in followed[n:], "the sim's states do not name the new solver"
            t = time.monotonic()
            while (alive := alive_solvers(z, keys)) != ["wqp"] and time.monotonic() - t < 10:
                time.sleep(0.2)
            assert alive == ["wqp"], "the old solver still runs"
            sub.undeclare()
        again = _mimic(env, "swap-solver", "--algo", "hqp-nullspace", "--id", "wqp")
        assert again.returncode == 1 and "a solver 'wqp' already runs" in again.stderr, again.stderr
    finally:
        up.send_signal(signal.SIGTERM)
        up.wait(120)
    log = out.read_text()
    assert "solver 'main' replaced by 'wqp' (wqp): the sim follows 'wqp', solver stopped" in log, log[-3000:]
    assert "without being asked" not in log and "crashed" not in log, log[-3000:]
    assert up.returncode == 0


def test_a_solver_stopped_from_outside_is_reported_as_such_not_as_exited_with_0(caplog):
    """What `mimic up` says when its solver exits 0 unasked: not a bare "exited with 0" warning."""
    import io

    from services.launcher.supervisor import Supervisor

    sup = Supervisor(out=io.StringIO())
    # A service that shuts down cleanly on SIGTERM, as every mimic service does.
    code = (
        "import signal, sys, time; signal.signal(signal.SIGTERM, lambda *a: sys.exit(0)); "
        "print('up', flush=True); time.sleep(60)"
    )
    child = sup.start("solver", [sys.executable, "-c", code], {})
    t = time.monotonic()
    while "up" not in sup.out.getvalue() and time.monotonic() - t < 30:
        time.sleep(0.05)
    os.kill(child.proc.pid, signal.SIGTERM)  # "from outside": not through the supervisor
    child.proc.wait(30)
    with caplog.at_level("INFO", logger="mimic"):
        assert sup.poll() == ["solver"]
    text = caplog.text
    assert "solver stopped (exit 0) without being asked by this stack" in text, text
    assert "mimic follow ID" in text and "mimic swap-solver" in text and "exited with 0" not in text
    sup.start("job", [sys.executable, "-c", "pass"], {}, service=False)  # a one-shot job: its exit is news-free
    sup.children["job"].proc.wait(30)
    caplog.clear()
    with caplog.at_level("INFO", logger="mimic"):
        sup.poll()
    assert "job finished" in caplog.text and "WARNING" not in caplog.text, caplog.text
