"""`mimic up` mistakes answered in one line: an unknown profile, a second stack on a running one."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from services.launcher.local_stack import LocalStack
from shared.bus import free_port
from shared.paths import REPO_ROOT, unused_path

pytestmark = pytest.mark.integration


def _up(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "up", *argv],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
    )


def _errors(run: subprocess.CompletedProcess) -> list[str]:
    return [ln for ln in (run.stdout + run.stderr).splitlines() if " E " in ln or "Traceback" in ln]


def test_unknown_profile_is_refused_naming_the_valid_ones():
    session = f"prof{free_port()}"
    run = _up("--profile", "bogus", "--session", session, "--endpoint", f"tcp/127.0.0.1:{free_port()}")
    assert run.returncode == 1, run
    errors = _errors(run)
    assert len(errors) == 1 and "unknown profile(s) ['bogus']; known: " in errors[0], run.stdout + run.stderr
    assert "live" in errors[0] and "shadow" in errors[0]
    assert not (REPO_ROOT / "runs" / f"{session}.lock").exists()


def test_a_second_up_refuses_and_leaves_the_first_stacks_files(zenoh_endpoint):
    session = f"first{zenoh_endpoint.rsplit(':', 1)[1]}"
    with LocalStack(session, zenoh_endpoint) as first:
        first.start_router()
        state = REPO_ROOT / "runs" / f"{session}_calibration.json"
        state.write_text('{"first": "stack"}')  # the first stack's calibration state
        try:
            same = _up("--session", session, "--endpoint", zenoh_endpoint, "--only", "retarget", "--duration", "1")
            assert same.returncode == 1
            errors = _errors(same)
            assert len(errors) == 1 and "already run by a live stack" in errors[0], same.stdout + same.stderr
            assert state.read_text() == '{"first": "stack"}', "the second stack touched the first one's state"

            other = f"{session}b"
            port = _up("--session", other, "--endpoint", zenoh_endpoint, "--only", "retarget", "--duration", "1")
            assert port.returncode == 1
            errors = _errors(port)
            assert len(errors) == 1 and f"router endpoint {zenoh_endpoint} is busy" in errors[0], port.stdout
            assert first.running("zenoh") and state.exists()

            t = time.monotonic()
            beside = _up("--session", session, "--beside", "--only", "solver", "--duration", "0.5")
            assert beside.returncode == 0, beside.stdout[-3000:] + beside.stderr[-3000:]
            assert f"stack up on session '{session}-2'" in beside.stdout + beside.stderr
            assert state.read_text() == '{"first": "stack"}' and first.running("zenoh")
            assert time.monotonic() - t < 120
        finally:
            for p in REPO_ROOT.glob(f"runs/{session}*_summary.json"):
                p.unlink()


def test_unused_path_never_names_an_existing_file(tmp_path):
    rrd = tmp_path / "s.rrd"
    assert unused_path(rrd) == rrd
    rrd.write_text("1")
    assert unused_path(rrd) == tmp_path / "s-1.rrd"
    (tmp_path / "s-1.rrd").write_text("2")
    assert unused_path(rrd) == tmp_path / "s-2.rrd"


def test_summaries_are_never_overwritten_unless_asked(tmp_path):
    """Each run's summary goes to a new file (like its recording); --overwrite replaces the asked one."""
    session = f"sum{free_port()}"
    earlier = REPO_ROOT / "runs" / f"{session}_summary.json"
    earlier.parent.mkdir(exist_ok=True)
    earlier.write_text('{"earlier": "run"}')
    try:
        for n in (1, 2):  # the router alone: the quickest stack that writes a summary
            run = _up("--session", session, "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--only", "zenoh",
                      "--duration", "0.3")  # fmt: skip
            assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
            written = REPO_ROOT / "runs" / f"{session}_summary-{n}.json"
            assert f"summary written: {written}" in run.stderr, run.stderr[-2000:]
            assert json.loads(written.read_text())["session"] == session
        assert earlier.read_text() == '{"earlier": "run"}', "a run overwrote an earlier summary"

        asked = tmp_path / "s.json"
        asked.write_text("{}")
        args = ("--session", session, "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--only", "zenoh",
                "--duration", "0.3", "--summary", str(asked))  # fmt: skip
        kept = _up(*args)
        assert kept.returncode == 0 and asked.read_text() == "{}"
        assert json.loads((tmp_path / "s-1.json").read_text())["session"] == session
        replaced = _up(*args, "--overwrite")
        assert replaced.returncode == 0 and json.loads(asked.read_text())["session"] == session
        assert not (tmp_path / "s-2.json").exists()
    finally:
        for p in REPO_ROOT.glob(f"runs/{session}_summary*.json"):
            p.unlink()
