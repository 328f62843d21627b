"""``mimic bench recorder``: does the recorder lose messages at rate R for D seconds?

Starts a router and a ``mimic record`` process on loopback, publishes
``rate * duration`` HumanFrames (seq 0..N-1) at ``rate`` Hz against absolute
deadlines, samples the recorder's RSS every ``--rss-period`` seconds, stops
the recorder with SIGINT, reads the file back and counts: published, found,
missing and duplicated sequence numbers. Prints JSON (and writes ``--json``).
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from services.launcher.local_stack import LocalStack
from services.launcher.supervisor import rss_mb
from services.recorder.mcap_io import read_recording
from shared.bus import free_port
from shared.keys import Keys
from shared.messages import HUMAN_BONES, Bone, Header, HumanFrame, Pose, ServiceStatus
from shared.report import emit_json

log = logging.getLogger("mimic.record-bench")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate", type=float, default=1000.0, help="publish rate [Hz]")
    p.add_argument("--duration", type=float, default=10.0, help="publish for this long [s]")
    p.add_argument("--json", default=None, help="also write the report here")
    p.add_argument("--out", default=None, help="keep the recording here (default: a temporary file)")
    p.add_argument("--rss-period", type=float, default=1.0, help="recorder RSS sampling period [s]")
    p.add_argument("--port", type=int, default=0, help="router port on 127.0.0.1 (0 = a free one)")
    p.add_argument("--session", default="recbench", help="session to publish into")


def make_frame(seq: int, rate: float) -> HumanFrame:
    """A full valid HumanFrame numbered ``seq`` (15 bones, like real mocap)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    bones = {n: Bone(np.array([0.01 * i, 0.1, 0.2 + 1e-6 * seq]), q) for i, n in enumerate(HUMAN_BONES)}
    return HumanFrame(Header(seq, seq / rate), "record-bench", Pose(np.zeros(3), q), bones)


def wait_recording(session: zenoh.Session, keys: Keys, timeout: float = 20.0) -> bool:
    """Wait until the recorder's ServiceStatus says it records (its subscriber is declared)."""
    ready = threading.Event()

    def on_status(sample: zenoh.Sample) -> None:
        try:
            st = ServiceStatus.decode(sample.payload.to_bytes())
        except Exception:
            return
        if st.service == "recorder" and st.state == "recording":
            ready.set()

    sub = session.declare_subscriber(keys.status("recorder"), on_status)
    ok = ready.wait(timeout)
    sub.undeclare()
    return ok


def _final_counts(output: str) -> dict:
    """The recorder's last JSON line (its final counts) from the stack's prefixed output."""
    for line in reversed(output.splitlines()):
        body = line.split(" | ", 1)[-1].strip()
        if body.startswith("{"):
            return json.loads(body)
    return {}


def run_bench(
    rate: float, duration: float, out: Path, port: int = 0, session: str = "recbench", rss_period: float = 1.0
) -> dict:
    """Router + recorder processes (a :class:`LocalStack`), publish, stop, count. Returns the report dict."""
    endpoint = f"tcp/127.0.0.1:{port or free_port()}"
    n_total = round(rate * duration)
    rss: list[tuple[float, float]] = []
    with LocalStack(session, endpoint) as stack:
        keys = stack.keys
        stack.start_router()
        stack.start("recorder", argv=["mimic", "record", "--out", str(out), "--status-period", "0.2"])
        z = stack.bus
        if not wait_recording(z, keys):
            raise RuntimeError(f"recorder did not come up within 20 s\n{stack.output()}")
        time.sleep(0.5)
        pub = z.declare_publisher(keys.mocap_frame, congestion_control=zenoh.CongestionControl.BLOCK, express=True)
        payloads = [make_frame(i, rate).encode() for i in range(min(n_total, 1000))]
        recorder_pid = stack.pid("recorder")
        t_start = time.monotonic()
        next_rss = t_start
        late_max = 0.0
        for i in range(n_total):
            due = t_start + i / rate
            now = time.monotonic()
            if due > now:
                time.sleep(due - now)
            else:
                late_max = max(late_max, now - due)
            # Re-encode only the header: building 600k frames up front would dominate the bench.
            frame = make_frame(i, rate).encode() if i >= len(payloads) else payloads[i]
            pub.put(frame)
            if now >= next_rss:
                r = rss_mb(recorder_pid)
                if r is not None:
                    rss.append((round(now - t_start, 2), round(r, 2)))
                next_rss += rss_period
        publish_s = time.monotonic() - t_start
        time.sleep(1.0)  # let the last samples cross the router
        pub.undeclare()
        stack.sup.stop("recorder", timeout=60)  # SIGTERM: it closes the file and prints its counts
        final = _final_counts(stack.output(tail=None))
    recording = read_recording(out)
    seqs = []
    for rec in recording:
        if rec.key == keys.mocap_frame:
            seqs.append(HumanFrame.decode(rec.data).hdr.seq)
    found = set(seqs)
    rss_vals = [v for _, v in rss]
    return {
        "rate_hz": rate,
        "duration_s": duration,
        "published": n_total,
        "publish_s": round(publish_s, 3),
        "publish_late_max_ms": round(1e3 * late_max, 3),
        "recorded": len(seqs),
        "lost": n_total - len(found & set(range(n_total))),
        "duplicates": len(seqs) - len(found),
        "in_order": seqs == sorted(seqs),
        "recorder_final": final,
        "file_complete": recording.complete,
        "file_mb": round(out.stat().st_size / 2**20, 3),
        "rss_mb_first": rss_vals[0] if rss_vals else None,
        "rss_mb_last": rss_vals[-1] if rss_vals else None,
        "rss_mb_max": max(rss_vals) if rss_vals else None,
        "rss_mb_samples": rss,
    }


def main(args: argparse.Namespace) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp) / "bench.mcap"
        report = run_bench(args.rate, args.duration, out, args.port, args.session, args.rss_period)
    emit_json(report, args.json, indent=1)
    return 0 if report["lost"] == 0 and report["duplicates"] == 0 else 1
