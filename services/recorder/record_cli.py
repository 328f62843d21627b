"""``mimic record``: write every message of a session to MCAP.

Subscribes to ``mimic/<session>/**`` (or every session with
``--all-sessions``) and writes each sample with its key, receive time and
``hdr.t0``. On SIGINT/SIGTERM or after ``--duration`` it drains the queue,
writes the MCAP summary and prints the final counts as JSON.
"""

from __future__ import annotations

import argparse
import threading
import time
from datetime import UTC, datetime

import zenoh

from services.recorder.recorder import Recorder
from shared.bus import ServiceRunner, add_bus_args
from shared.keys import Keys
from shared.report import emit_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_args(p)
    p.add_argument("--out", default=None, help="output file (default runs/<session>-<UTC time>.mcap)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: until SIGINT)")
    p.add_argument("--all-sessions", action="store_true", help="record mimic/** instead of mimic/<session>/**")
    p.add_argument("--flush-period", type=float, default=0.2, help="flush period [s]: most lost on SIGKILL")
    p.add_argument("--chunk-size", type=int, default=256 * 1024, help="MCAP chunk size [bytes]")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")


def main(args: argparse.Namespace) -> int:
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    out = args.out or f"runs/{args.session}-{stamp}.mcap"
    rec = Recorder(out, flush_period=args.flush_period, chunk_size=args.chunk_size, compression=args.compression)
    with ServiceRunner("recorder", args) as svc:
        key = Keys.all_sessions() if args.all_sessions else svc.keys.everything

        def on_sample(sample: zenoh.Sample) -> None:
            # Only copy and enqueue here: this runs on a Zenoh thread.
            rec.on_message(str(sample.key_expr), sample.payload.to_bytes(), time.time_ns())

        sub = svc.session.declare_subscriber(key, on_sample)
        writer_done = threading.Event()

        def write_loop() -> None:
            try:
                while not writer_done.is_set():
                    rec.step(timeout=0.05)
                    svc.status.extra["queued"] = float(rec.queued)
                    svc.status.extra["written"] = float(rec.written)
                    svc.status.extra["received"] = float(rec.received)
                    svc.status.extra["frames_missing"] = float(rec.gaps.missing)
            except Exception as exc:  # a full disk must be visible, not silent
                svc.status.error(f"writer failed: {type(exc).__name__}: {exc}")
                svc.stop_event.set()

        writer = threading.Thread(target=write_loop, name="recorder-writer", daemon=True)
        writer.start()
        svc.status.state = "recording"
        svc.log.info("recording %s to %s", key, out)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        while not svc.stop_event.wait(0.1):
            if deadline is not None and time.monotonic() >= deadline:
                break
        sub.undeclare()
        writer_done.set()
        writer.join()
        try:
            counts = rec.close()
        except Exception as exc:  # disk full / removed: report what was written, fail loudly
            svc.status.error(f"closing {out} failed: {type(exc).__name__}: {exc}")
            counts = {"received": rec.received, "written": rec.written, "max_queue": rec.max_queue}
        counts["frames_missing"] = rec.gaps.missing
        svc.status.extra.update({k: float(v) for k, v in counts.items()})
        svc.log.info(
            "recorded %d messages (%d received) to %s; %d mocap frame(s) lost on the bus before the recorder "
            "(seq gaps)",
            counts["written"],
            counts["received"],
            out,
            counts["frames_missing"],
        )
    emit_json({"out": str(out), **counts}, indent=None)
    return 0 if counts["written"] == counts["received"] else 1
