"""Real processes on a real Zenoh bus: messages flow, SIGKILL is noticed through liveliness."""

from __future__ import annotations

import json
import sys
import time

import pytest
import zenoh

from shared.bus import ServiceRunner, bus_args, zenoh_config
from shared.keys import Keys
from shared.messages import ServiceStatus

PEER = [sys.executable, "-m", "tests.support.bus_peer"]
pytestmark = pytest.mark.integration


def _wait_output(stack, text: str, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in stack.output(tail=None):
            return True
        time.sleep(0.05)
    return False


def test_two_processes_exchange_messages_and_survive_a_sigkill(local_stack):
    stack = local_stack
    stack.start_router()
    stack.start("listener", argv=[*PEER, "listener", "--status-period", "0.2"])
    stack.start("talker", argv=[*PEER, "talker", "--status-period", "0.2"])
    stack.wait_alive(["listener/main", "talker/main"], timeout=60)

    statuses: dict[str, ServiceStatus] = {}
    keys = stack.keys
    sub = stack.bus.declare_subscriber(
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

    assert _wait_output(stack, "alive/talker/main"), stack.output()
    stack.kill9("talker")
    assert _wait_output(stack, "DELETE"), "listener did not notice the killed talker:\n" + stack.output()
    # The listener keeps running and keeps reporting.
    before = statuses[keys.status("listener")].uptime
    time.sleep(0.8)
    assert stack.running("listener")
    assert statuses[keys.status("listener")].uptime > before
    sub.undeclare()

    assert stack.sup.stop("listener", timeout=10) == 0
    assert _wait_output(stack, "listener/main stopped"), stack.output()


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


def test_the_last_status_says_stopping_and_carries_the_last_figures(router):
    """A service's final status is refreshed through ``before_status`` and still says "stopping"."""
    keys = Keys("st_stop")
    got: list[ServiceStatus] = []
    client = zenoh.open(zenoh_config(bus_args(connect=[router])))
    client.declare_subscriber(keys.status("probe"), lambda s: got.append(ServiceStatus.decode(s.payload.to_bytes())))
    time.sleep(0.3)  # let the subscription reach the router
    work = {"done": 0}
    args = bus_args(connect=[router], session="st_stop", status_period=0.1)
    with ServiceRunner("probe", args, install_signals=False) as svc:

        def refresh() -> None:
            svc.status.extra["done"] = float(work["done"])
            svc.status.state = "ok"  # what a service's refresh says while it runs

        svc.before_status = refresh
        # The new session learns of the client's subscription through the router a moment after it
        # opens (longer under load); a put before that reaches nobody. Wait for a periodic status.
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not got:
            time.sleep(0.05)
        assert got, "no periodic status reached the subscriber"
        assert got[-1].state == "ok"
        work["done"] = 7  # done after the last periodic status
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and not (got and got[-1].state == "stopping"):
        time.sleep(0.05)
    client.close()
    assert got and got[-1].state == "stopping", [s.state for s in got]
    assert got[-1].extra["done"] == 7.0
