"""The sim service on a real Zenoh bus (loopback): follow switch, state stream, watchdog, rejects."""

from __future__ import annotations

import threading
import time

import msgpack
import numpy as np
import pytest

from services.sim.node import SimNode, parse_follow
from services.sim.sim_core import SimCore
from shared.bus import ServiceRunner, bus_args, open_session, query
from shared.messages import Header, JointCommand, RobotState, ServiceStatus

pytestmark = pytest.mark.integration
SESSION = "simtest"


def test_parse_follow_accepts_text_msgpack_and_maps_and_refuses_bad_ids():
    assert parse_follow(b"alt") == "alt"
    assert parse_follow(msgpack.packb("hqp_2")) == "hqp_2"
    assert parse_follow(msgpack.packb({"follow": "qp"})) == "qp"
    assert parse_follow(b'{"follow": "dls"}') == "dls"
    for bad in (b"a/b", b"", msgpack.packb(3), msgpack.packb({"x": "y"})):
        with pytest.raises(ValueError):
            parse_follow(bad) if bad else parse_follow(b" ")


def _wait(pred, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.02)
    return False


@pytest.mark.slow
def test_follow_switch_watchdog_and_rejects_over_zenoh(zenoh_endpoint):
    hub = open_session(bus_args(mode="router", listen=[zenoh_endpoint], connect=[]))
    core = SimCore()
    elbow = core.joint_names.index(core.robot.profile.arms["left"].elbow)
    q_main = core.q.copy()
    q_main[elbow] = 0.4
    q_alt = core.q.copy()
    q_alt[elbow] = 1.0
    stop = threading.Event()
    states: list[RobotState] = []
    statuses: list[ServiceStatus] = []
    try:
        args = bus_args(connect=[zenoh_endpoint], session=SESSION, status_period=0.1)
        with ServiceRunner("sim", args, install_signals=False) as svc:
            node = SimNode(core, svc, state_rate=200.0)
            loop = threading.Thread(target=node.run_realtime, args=(stop,), daemon=True)
            loop.start()
            with open_session(bus_args(connect=[zenoh_endpoint], session=SESSION)) as z:
                keys = svc.keys
                z.declare_subscriber(keys.sim_state, lambda s: states.append(RobotState.decode(s.payload.to_bytes())))
                z.declare_subscriber(
                    keys.status("sim"), lambda s: statuses.append(ServiceStatus.decode(s.payload.to_bytes()))
                )
                pubs = {sid: z.declare_publisher(keys.command(sid)) for sid in ("main", "alt")}
                seq = {"main": 1000, "alt": 5000}
                sending = threading.Event()
                sending.set()

                def send(sid, q, bad=False):
                    seq[sid] += 1
                    qq = q.copy()
                    if bad:
                        qq[elbow] = 9.0  # beyond the URDF limit
                    hdr = Header(seq[sid], seq[sid] * 0.01)
                    cmd = JointCommand(hdr, sid, "test", list(core.joint_names), qq, 0 * qq)
                    pubs[sid].put(cmd.encode())

                def talker():
                    while not stop.is_set():
                        if sending.is_set():
                            send("main", q_main)
                            send("alt", q_alt)
                        time.sleep(0.01)

                threading.Thread(target=talker, daemon=True).start()

                assert _wait(lambda: len(states) > 50 and states[-1].hdr.seq > 1000), "no RobotState"
                assert msgpack.unpackb(query(z, keys.sim_follow)) == {"follow": "main"}
                assert _wait(lambda: abs(states[-1].q[elbow] - 0.4) < 0.02)
                recent = states[-20:]
                assert all(s.solver_id == "main" and 1000 < s.hdr.seq < 5000 for s in recent)

                # Switch to "alt" through the queryable.
                assert msgpack.unpackb(query(z, keys.sim_follow, b"alt")) == {"follow": "alt"}
                assert _wait(lambda: states[-1].hdr.seq > 5000 and abs(states[-1].q[elbow] - 1.0) < 0.02)
                assert states[-1].solver_id == "alt"
                with pytest.raises(RuntimeError):
                    query(z, keys.sim_follow, b"not/an/id")
                assert msgpack.unpackb(query(z, keys.sim_follow)) == {"follow": "alt"}

                # State rate: >= 200 Hz of (real-time) simulated time.
                n0, t0 = len(states), time.monotonic()
                time.sleep(1.0)
                rate = (len(states) - n0) / (time.monotonic() - t0)
                assert rate > 150, rate  # 200 Hz nominal; loopback + CI jitter margin

                # Commands stop: the watchdog holds and says so.
                sending.clear()
                assert _wait(lambda: states[-1].holding and statuses and statuses[-1].state == "holding")
                held = states[-1].q.copy()
                time.sleep(0.3)
                assert np.max(np.abs(states[-1].q - held)) < np.deg2rad(0.5)

                # A command beyond the limits is counted and not applied.
                send("alt", q_alt, bad=True)
                assert _wait(lambda: statuses[-1].rejects.get("limits", 0) == 1)
                time.sleep(0.1)
                assert states[-1].holding and abs(states[-1].q[elbow] - held[elbow]) < 0.01
                stop.set()
                loop.join(5)
                assert not loop.is_alive()
            assert node.ignored > 0  # the other solver's commands were seen and left alone
    finally:
        stop.set()
        hub.close()


def test_lockstep_over_zenoh_advances_once_per_command_in_order(zenoh_endpoint):
    hub = open_session(bus_args(mode="router", listen=[zenoh_endpoint], connect=[]))
    core = SimCore()
    stop = threading.Event()
    states: list[RobotState] = []
    n = 50
    try:
        args = bus_args(connect=[zenoh_endpoint], session="simlock")
        with ServiceRunner("sim", args, install_signals=False) as svc:
            node = SimNode(core, svc, lockstep=True, lockstep_dt=0.01)
            loop = threading.Thread(target=node.run_lockstep, args=(stop,), daemon=True)
            loop.start()
            with open_session(bus_args(connect=[zenoh_endpoint], session="simlock")) as z:
                z.declare_subscriber(
                    svc.keys.sim_state, lambda s: states.append(RobotState.decode(s.payload.to_bytes()))
                )
                pub = z.declare_publisher(svc.keys.command("main"))
                time.sleep(0.5)
                assert states == []  # lock-step: no command, no time, no state
                q = core.q.copy()
                for k in range(n):
                    q[core.joint_names.index(core.robot.profile.arms["right"].elbow)] = 1.2 - 0.01 * k
                    pub.put(JointCommand(Header(k, k * 0.01), "main", "t", list(core.joint_names), q, 0 * q).encode())
                assert _wait(lambda: len(states) == n)
            stop.set()
            loop.join(5)
    finally:
        stop.set()
        hub.close()
    assert [s.hdr.seq for s in states] == list(range(n))
    assert [round(s.sim_time, 6) for s in states] == [round(0.01 * (k + 1), 6) for k in range(n)]


def test_realtime_loop_wakes_for_states_and_commands_not_for_every_physics_step(zenoh_endpoint):
    """Real time without commands: physics keeps the wall clock and the states come at --state-rate, but the
    loop sleeps until a state is due (the 1 ms steps run in batches) instead of waking for every step."""
    hub = open_session(bus_args(mode="router", listen=[zenoh_endpoint], connect=[]))
    try:
        args = bus_args(connect=[zenoh_endpoint], session=SESSION + "wake", status_period=0.5)
        with ServiceRunner("sim", args, install_signals=False) as svc:
            core = SimCore()
            node = SimNode(core, svc, state_rate=100.0)
            take = node.commands.take
            calls = []
            node.commands.take = lambda timeout=None: calls.append(timeout) or take(timeout)
            published = []
            publish = node._publish
            node._publish = lambda: published.append(core.time) or publish()
            wall = time.monotonic()
            node.run_realtime(threading.Event(), duration=1.0)
            wall = time.monotonic() - wall
        steps = round(core.time / core.dt)
        assert steps >= 1000 and wall >= 0.99  # paced: 1 s of simulated time took 1 s
        assert abs(len(published) - (round(core.time / 0.01) + 1)) <= 1  # 100 Hz of simulated time (from t = 0)
        # One sleep per state period (and the 0.1 s status), not one per 1 ms physics step (the former loop's ~950);
        # a loop that comes back late only looks at the mailbox without sleeping (timeout None).
        sleeps = [t for t in calls if t is not None]
        assert len(sleeps) < 300, len(sleeps)
    finally:
        hub.close()
