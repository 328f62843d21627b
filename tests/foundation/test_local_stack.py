"""The one way to start a local stack: readiness on liveliness, clear errors, the README snippet."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from services.launcher.local_stack import LocalStack, mimic_argv
from services.launcher.stack import REPO_ROOT

pytestmark = pytest.mark.integration
README = REPO_ROOT / "services" / "launcher" / "README.md"


def test_readme_snippet_runs():
    block = re.search(r"```python\n(.*?)```", README.read_text(), re.S)
    assert block, "no python snippet in the launcher README"
    exec(compile(block.group(1), str(README), "exec"), {})


def test_start_all_returns_when_alive_and_close_stops_everything(local_stack):
    t = time.monotonic()
    local_stack.start_all(["solver"], timeout=120)
    assert not local_stack.missing(["solver/main"]), "start_all returned before the liveliness token"
    pid = local_stack.pid("solver")
    assert pid is not None and local_stack.running("solver")
    codes = local_stack.close()
    assert codes == {"solver": 0, "zenoh": codes["zenoh"]} and list(codes) == ["solver", "zenoh"], codes
    assert not Path(f"/proc/{pid}").exists() or not local_stack.running("solver")
    assert time.monotonic() - t < 120


def test_a_service_that_exits_at_start_up_is_named(local_stack):
    local_stack.start_router()
    local_stack.start("bad", argv=["mimic", "solve", "--algo", "no-such-algo"])
    with pytest.raises(RuntimeError, match=r"exited during start-up: \['bad'\]"):
        local_stack.wait_alive(["solver"], timeout=60)


def test_mimic_argv_uses_this_interpreter():
    import sys

    assert mimic_argv(["mimic", "sim"]) == [sys.executable, "-m", "services.cli", "sim"]
    assert mimic_argv(["ls"]) == ["ls"]


def test_wait_needs_the_router():
    with LocalStack("nowhere", "tcp/127.0.0.1:1") as stack, pytest.raises(RuntimeError, match="router first"):
        stack.wait_alive(["sim"])
