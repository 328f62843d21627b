"""The retarget service on a real Zenoh bus over loopback: in-process node and the `mimic retarget` process."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import time

import msgpack
import numpy as np
import pytest
import zenoh
from conftest import make_frame

from services.retarget import node as node_module
from services.retarget.calibration import anthropometric
from services.retarget.node import RetargetNode
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.bus import ServiceRunner, bus_args, query, sample_number, zenoh_config
from shared.keys import Keys
from shared.messages import TaskTargets
from shared.robot.profile import DEFAULT_PROFILE
from shared.targets import TARGET_NAMES

pytestmark = pytest.mark.integration


def _client(endpoint: str) -> zenoh.Session:
    return zenoh.open(zenoh_config(bus_args(connect=[endpoint])))


def _collect(q: queue.Queue, n: int, timeout: float) -> list[TaskTargets]:
    out, deadline = [], time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        try:
            out.append(q.get(timeout=0.1))
        except queue.Empty:
            pass
    return out


def test_node_retargets_every_frame_and_serves_calibration(router, robot14, workspace, tmp_path, monkeypatch):
    # The node runs inside the test process (the whole suite's heap and threads): once in CI its worker stalled
    # past FRAME_MAX_AGE (0.1 s) mid-burst and skipped frames 17-19 as stale, as designed. That policy has its own
    # test (test_bus_drops); this one checks that every frame comes through, so a stall must not count.
    monkeypatch.setattr(node_module, "FRAME_MAX_AGE", 2.0)
    keys = Keys("rt_node")
    args = bus_args(connect=[router], session="rt_node", status_period=0.2)
    r = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    with ServiceRunner("retarget", args, install_signals=False) as svc:
        node = RetargetNode(r, svc, save_calibration=[tmp_path / "cal.json"])
        client = _client(router)
        got: queue.Queue = queue.Queue()
        numbers: dict[int, int] = {}  # seq -> the node publisher's sample number (shared.bus.NumberedPublisher)

        def on_targets(sample: zenoh.Sample) -> None:
            tt = TaskTargets.decode(sample.payload.to_bytes())
            numbers[tt.hdr.seq] = sample_number(sample)[1]
            got.put(tt)

        client.declare_subscriber(keys.targets, on_targets)
        pub = client.declare_publisher(keys.mocap_frame)
        time.sleep(0.5)  # let the subscriptions propagate through the router
        assert msgpack.unpackb(query(client, keys.calibration)) == {"calibrated": False}

        for i in range(1, 21):
            pub.put(make_frame(i, i / 30, offsets={"left_wrist": np.array([0.0, 0.0, 0.01 * i])}, t0=1000 + i).encode())
            time.sleep(0.005)  # 200 Hz, above any mocap rate (sent at once, the targets went out in one burst)
        pub.put(make_frame(20, 0.9, t0=1020).encode())  # duplicated seq (a duplicate keeps its t0)
        pub.put(b"\x93garbage")  # not a HumanFrame
        outs = _collect(got, 20, timeout=5.0)
        # Every frame is retargeted and published in order (the node's count below says all 20 went out). On the way
        # to this subscriber Zenoh's DROP congestion control may lose some on a loaded machine (shared/bus.py: by
        # design, counted as gaps by the receiver): 1-6 of the 20 in 1 run of 8-16 with two busy loops beside the
        # test, and once in a full suite run. Each sample's number is its frame's seq, so a missing frame is
        # exactly such a counted gap, never one the node skipped.
        seqs = [o.hdr.seq for o in outs]
        assert len(outs) >= 10 and seqs == sorted(set(seqs)) and set(seqs) <= set(range(1, 21))
        assert all(numbers[q] == q for q in seqs), numbers
        assert [o.hdr.t0 for o in outs] == [1000 + q for q in seqs]
        assert outs[-1].targets["left_wrist"].p[2] > outs[0].targets["left_wrist"].p[2]
        time.sleep(0.2)
        node.update_status()
        snap = svc.status.snapshot()
        assert snap.rejects.get("duplicate_seq") == 1 and snap.rejects.get("msgpack") == 1
        assert snap.counts["published.targets"] == 20 and snap.state == "ok"

        cal = msgpack.unpackb(query(client, keys.calibration))
        assert cal["calibrated"] and cal["source"] == "anthropometric"
        assert json.loads((tmp_path / "cal.json").read_text())["rest"] == cal["rest"]

        # set a calibration through the queryable (JSON payload): rest 5 cm lower -> targets move
        new = anthropometric(make_frame(0, 0.0, offsets={"left_wrist": np.array([0.0, 0.0, -0.05])})).to_dict()
        reply = msgpack.unpackb(query(client, keys.calibration, json.dumps(new).encode()))
        assert reply["source"] == "anthropometric" and reply["rest"] == new["rest"]
        assert r.calibration.rest["left_wrist"][2] == pytest.approx(new["rest"]["left_wrist"][2])
        with pytest.raises(RuntimeError, match="lacks field"):
            query(client, keys.calibration, msgpack.packb({"rest": {}}))
        cfg = msgpack.unpackb(query(client, keys.config("retarget")))
        assert cfg["config"]["mode"] == RetargetConfig().mode and set(TARGET_NAMES) <= set(cfg["workspace"])
        client.close()


def test_mimic_retarget_process_starts_publishes_and_stops_on_sigterm(router, tmp_path):
    env = dict(os.environ, MIMIC_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=os.getcwd())
    cmd = [sys.executable, "-m", "services.cli", "retarget", "--connect", router, "--session", "rt_proc",
           "--samples", "2000", "--mapping", "paper"]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    keys = Keys("rt_proc")
    client = _client(router)
    try:
        got: queue.Queue = queue.Queue()
        client.declare_subscriber(keys.targets, lambda s: got.put(TaskTargets.decode(s.payload.to_bytes())))
        deadline = time.monotonic() + 30
        while not list(client.liveliness().get(keys.alive("retarget", "main"), timeout=0.5)):
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() < deadline, "mimic retarget did not come up"
        time.sleep(0.3)  # its subscriber is declared right after the token
        pub = client.declare_publisher(keys.mocap_frame)
        for i in range(1, 6):
            pub.put(make_frame(i, i / 30).encode())
        outs = _collect(got, 5, timeout=5.0)
        assert [o.hdr.seq for o in outs] == [1, 2, 3, 4, 5]
        assert outs[0].mode == "paper"
    finally:
        client.close()
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert rc == 0, proc.stderr.read()
    assert list((tmp_path / "cache").glob(f"workspace_{DEFAULT_PROFILE}_2000_0_*.npz"))
