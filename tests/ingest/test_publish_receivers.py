"""`mimic publish` into nothing fails in one line instead of playing the clip and exiting 0."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from services.ingest import generate_demo_clips
from shared.bus import free_port
from shared.paths import REPO_ROOT

pytestmark = pytest.mark.integration


def _publish(clip, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "publish", str(clip), "--wait-subscriber", "1", *argv],
        cwd=REPO_ROOT,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_publish_without_router_or_subscriber_is_an_error(tmp_path, local_stack):
    clip = generate_demo_clips(tmp_path)[1]
    nobody = _publish(clip, "--connect", f"tcp/127.0.0.1:{free_port()}", "--session", "nobody")
    assert nobody.returncode == 2
    err = [ln for ln in nobody.stderr.splitlines() if " E " in ln]
    assert len(err) == 1 and "no router reachable at tcp/127.0.0.1:" in err[0], nobody.stderr
    assert '"frames"' not in nobody.stdout  # nothing claims to have been played
    local_stack.start_router()  # a router, but no stack on this session
    empty = _publish(clip, "--connect", local_stack.endpoint, "--session", "nobody")
    assert empty.returncode == 2
    err = [ln for ln in empty.stderr.splitlines() if " E " in ln]
    assert len(err) == 1 and "nothing subscribes to mimic/nobody/mocap/frame" in err[0], empty.stderr
