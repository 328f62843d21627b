"""Real processes on a real Zenoh bus: messages flow, SIGKILL is noticed through liveliness."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from shared.bus import bus_args, open_session
from shared.keys import Keys
from shared.messages import ServiceStatus
from shared.paths import REPO_ROOT

REPO = REPO_ROOT
PEER = Path(__file__).with_name("bus_peer.py")
pytestmark = pytest.mark.integration


def _spawn(argv, **kw):
    return subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


class _Lines:
    def __init__(self, proc):
        self.lines: list[str] = []
        threading.Thread(target=self._read, args=(proc,), daemon=True).start()

    def _read(self, proc):
        for line in proc.stdout:
            self.lines.append(line)

    def wait_for(self, text, timeout=10.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in ln for ln in self.lines):
                return True
            time.sleep(0.05)
        return False


def test_two_processes_exchange_messages_and_survive_a_sigkill(zenoh_endpoint):
    router = _spawn([sys.executable, "-m", "services.cli", "router", "--listen", zenoh_endpoint])
    procs = [router]
    try:
        time.sleep(1.0)
        common = ["--connect", zenoh_endpoint, "--session", "bustest", "--status-period", "0.2"]
        listener = _spawn([sys.executable, str(PEER), "listener", *common])
        talker = _spawn([sys.executable, str(PEER), "talker", *common])
        procs += [listener, talker]
        out = _Lines(listener)

        statuses: dict[str, ServiceStatus] = {}
        with open_session(bus_args(connect=[zenoh_endpoint], session="bustest")) as z:
            keys = Keys("bustest")
            z.declare_subscriber(
                keys.all_status,
                lambda s: statuses.__setitem__(str(s.key_expr), ServiceStatus.decode(s.payload.to_bytes())),
            )
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                st = statuses.get(keys.status("listener"))
                # Count what arrived, not the talker's seq: the listener may join a few frames late.
                if st and st.counts.get("received.frames", 0) > 20:
                    break
                time.sleep(0.1)
            st = statuses[keys.status("listener")]
            assert st.counts.get("received.frames", 0) > 20, st
            assert st.rejects == {}

            assert out.wait_for("alive/talker/main"), "".join(out.lines)
            talker.send_signal(signal.SIGKILL)
            talker.wait(5)
            assert out.wait_for("DELETE"), "listener did not notice the killed talker:\n" + "".join(out.lines)
            # The listener keeps running and keeps reporting.
            before = statuses[keys.status("listener")].uptime
            time.sleep(0.8)
            assert listener.poll() is None
            assert statuses[keys.status("listener")].uptime > before

        listener.send_signal(signal.SIGTERM)
        assert listener.wait(10) == 0
        assert out.wait_for("listener/main stopped")
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()


def test_zenoh_config_defaults_and_flags(tmp_path, monkeypatch):
    from shared.bus import zenoh_config

    monkeypatch.delenv("ZENOH_CONFIG", raising=False)
    monkeypatch.setenv("MIMIC_CONNECT", "tcp/127.0.0.1:1234")
    conf = zenoh_config(bus_args())
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:1234"]
    conf = zenoh_config(bus_args(connect=["tcp/127.0.0.1:9"], mode="client"))
    assert json.loads(conf.get_json("mode")) == "client"
    f = tmp_path / "z.json5"
    f.write_text('{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:77"]}}')
    monkeypatch.setenv("ZENOH_CONFIG", str(f))
    conf = zenoh_config(bus_args())
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:77"]
    assert isinstance(conf, zenoh.Config)
