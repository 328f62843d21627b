"""Playback and the UDP/Xsens bridge on a real Zenoh router on loopback."""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from services.ingest import cli as ingest_cli
from services.ingest import generate_demo_clips, load_clip
from services.ingest.playback import Playback
from services.ingest.xsens import build_datagrams
from shared.bus import bus_args, open_session
from shared.keys import Keys
from shared.messages import Bone, Header, HumanFrame, Pose
from shared.paths import REPO_ROOT
from tests.conftest import free_port

REPO = REPO_ROOT
pytestmark = pytest.mark.integration


class Collector:
    def __init__(self):
        self.items: list[tuple[float, HumanFrame]] = []
        self.lock = threading.Lock()

    def __call__(self, sample):
        f = HumanFrame.decode(sample.payload.to_bytes())
        with self.lock:
            self.items.append((time.monotonic(), f))

    def wait(self, n, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.lock:
                if len(self.items) >= n:
                    return True
            time.sleep(0.01)
        return False


def test_playback_schedule_loops_monotonic(tmp_path):
    clip = load_clip(generate_demo_clips(tmp_path)[0]).slice(0.0, 0.1)  # 7 frames at 60 Hz
    pb = Playback(clip, rate=2.0, loop=True, first_seq=10)
    frames, deadlines = [], []
    for _ in range(20):
        deadlines.append(pb.deadline(100.0))
        frames.append(pb.step(0))
    stamps = np.array([f.hdr.stamp for f in frames])
    assert [f.hdr.seq for f in frames] == list(range(10, 30))
    assert np.allclose(np.diff(stamps), 1 / 60)  # loop boundary included: no jump, no repeat
    assert np.allclose(np.diff(deadlines), 1 / 120)  # rate 2: twice as fast
    assert np.allclose(frames[7].bones["right_wrist"].p, frames[0].bones["right_wrist"].p)  # looped
    once = Playback(clip)
    [once.step(0) for _ in range(clip.n_frames)]
    assert once.done
    with pytest.raises(StopIteration):
        once.step(0)


def test_publish_subprocess_delivers_every_frame_in_order(router, tmp_path):
    path = generate_demo_clips(tmp_path)[1]
    clip = load_clip(path).slice(1.0, 3.0)
    session = "pubtest"
    got = Collector()
    with open_session(bus_args(connect=[router], session=session)) as z:
        sub = z.declare_subscriber(Keys(session).mocap_frame, got)
        proc = subprocess.run(
            [sys.executable, "-m", "services.cli", "publish", str(path), "--start", "1", "--end", "3",
             "--connect", router, "--session", session, "--wait-subscriber", "10"],
            cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"}, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert got.wait(clip.n_frames, 5.0)
        sub.undeclare()
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["frames"] == clip.n_frames
    t = np.array([a for a, _ in got.items])
    frames = [f for _, f in got.items]
    assert [f.hdr.seq for f in frames] == list(range(clip.n_frames))
    assert np.allclose([f.hdr.stamp for f in frames], clip.times, atol=1e-9)
    assert np.allclose(frames[30].bones["right_wrist"].p, clip.positions["right_wrist"][30])
    assert all(f.source == "bvh:ellipse.bvh" for f in frames)
    # timing at the publisher (hdr.t0 = wall clock at publish): the clip's duration at 60 Hz
    t0 = 1e-9 * np.array([f.hdr.t0 for f in frames])
    assert np.all(np.diff(t0) > 0)
    assert abs((t0[-1] - t0[0]) - clip.duration) < 0.1, t0[-1] - t0[0]
    assert abs(np.median(np.diff(t0)) - 1 / 60) < 0.003
    # and at the subscriber, allowing for loopback delivery jitter on a loaded machine
    assert abs((t[-1] - t[0]) - clip.duration) < 0.4, t[-1] - t[0]


def _frame(seq, left=(0.3, 0.2, 0.1)):
    q = np.array([1.0, 0.0, 0.0, 0.0])
    bones = {"pelvis": Bone(np.zeros(3), q), "left_wrist": Bone(np.array(left, float), q)}
    return HumanFrame(Header(seq, seq / 30.0, time.time_ns()), "udp-test", Pose(np.array([0, 0, 1.0]), q), bones)


def test_udp_and_xsens_bridge(router):
    session = "udptest"
    udp_port, mvn_port = free_port(), free_port()
    p = argparse.ArgumentParser()
    ingest_cli.add_arguments(p)
    args = p.parse_args(["--udp", f":{udp_port}", "--xsens", f"127.0.0.1:{mvn_port}", "--connect", router,
                         "--session", session])  # fmt: skip
    stop, ready, result = threading.Event(), threading.Event(), {}
    th = threading.Thread(target=lambda: result.update(ingest_cli.run(args, stop, ready)), daemon=True)
    th.start()
    got = Collector()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert ready.wait(10)
        with open_session(bus_args(connect=[router], session=session)) as z:
            z.declare_subscriber(Keys(session).mocap_frame, got)
            seq = 0
            while not got.wait(1, 0.1):  # warm-up until the route exists
                tx.sendto(_frame(seq).encode(), ("127.0.0.1", udp_port))
                seq += 1
                assert seq < 100
            time.sleep(0.2)
            base = seq + 10
            n0 = len(got.items)
            # A duplicated and a late datagram are the same bytes again (same seq and t0); a frame with a
            # lower seq but a later t0 would be a restarted sender, which is accepted at once.
            first, second = _frame(base).encode(), _frame(base + 1).encode()
            sends = [first, second, second, first, _frame(base + 2, (np.nan, 0, 0)).encode()]
            for dg in sends:
                tx.sendto(dg, ("127.0.0.1", udp_port))
            tx.sendto(b"\x00not msgpack", ("127.0.0.1", udp_port))
            tx.sendto(_frame(base + 3).encode(), ("127.0.0.1", udp_port))
            q = np.array([1.0, 0, 0, 0])
            segs = {1: (np.array([0.0, 0.0, 100.0]), q), 14: (np.array([30.0, 20.0, 120.0]), q)}
            for dg in build_datagrams(77, 1000, segs):
                tx.sendto(dg, ("127.0.0.1", mvn_port))
            assert got.wait(n0 + 5, 5.0)
            time.sleep(0.3)
    finally:
        stop.set()
        th.join(10)
        tx.close()
    frames = [f for _, f in got.items[n0:]]
    udp = [f for f in frames if f.source == "udp-test"]
    assert [f.hdr.seq for f in udp] == [base, base + 1, base + 2, base + 3]
    assert udp[2].bones["left_wrist"].valid is False and np.allclose(udp[2].bones["left_wrist"].p, [0.3, 0.2, 0.1])
    mvn = [f for f in frames if f.source == "xsens"]
    assert len(mvn) == 1 and mvn[0].hdr.seq == 77
    assert np.allclose(mvn[0].bones["left_elbow"].p, [0.3, 0.2, 0.2], atol=1e-6)
    rejects = result["rejects"]
    assert rejects.get("duplicate_seq") == 1 and rejects.get("seq_backwards") == 1
    assert rejects.get("nan_bone") == 1 and rejects.get("msgpack") == 1


def test_cli_errors_are_clear(tmp_path):
    bad = tmp_path / "broken.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    proc = subprocess.run(
        [sys.executable, "-m", "services.cli", "publish", str(bad), "--connect", "tcp/127.0.0.1:1"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2 and "no MOTION section" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "services.cli", "ingest"], cwd=REPO, capture_output=True, text=True,
                          timeout=60)  # fmt: skip
    assert proc.returncode == 2 and "give --udp HOST:PORT" in proc.stderr
    assert ingest_cli.parse_endpoint(":9870") == ("127.0.0.1", 9870)
    assert ingest_cli.parse_endpoint("0.0.0.0:1") == ("0.0.0.0", 1)
    with pytest.raises(ValueError, match="port"):
        ingest_cli.parse_endpoint("host:abc")


def test_publish_wrist_only_sends_hands_only_over_zenoh(router, tmp_path):
    path = generate_demo_clips(tmp_path)[1]
    session = "pubwrist"
    got = Collector()
    with open_session(bus_args(connect=[router], session=session)) as z:
        sub = z.declare_subscriber(Keys(session).mocap_frame, got)
        proc = subprocess.run(
            [sys.executable, "-m", "services.cli", "publish", str(path), "--start", "1", "--end", "1.5", "--wrist-only",
             "--connect", router, "--session", session, "--wait-subscriber", "10"],
            cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"}, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert got.wait(10, 5.0)
        sub.undeclare()
    assert json.loads(proc.stdout.strip().splitlines()[-1])["wrist_only"] is True
    for _, f in got.items:
        assert {"left_wrist", "right_wrist"} <= set(f.bones) <= {"left_wrist", "right_wrist", "left_hand", "right_hand"}
