"""``mimic replay FILE``: republish an MCAP recording onto the bus.

Original timing (scaled by ``--speed``) against absolute monotonic deadlines,
or ``--fast``. ``--only`` keeps a subset of keys; ``--session NEW``
republishes into ``mimic/NEW/...`` instead of the recorded session, e.g. replay
only the mocap frames of a session into a new one where another solver runs,
then compare the two.
"""

from __future__ import annotations

import argparse
import logging
import time

import zenoh

from services.recorder.mcap_io import read_recording
from services.recorder.replay import ReplayPlan
from shared.bus import ServiceRunner, add_bus_args
from shared.keys import DEFAULT_SESSION, Keys
from shared.messages import restamp
from shared.report import emit_json

log = logging.getLogger("mimic.replay")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_bus_args(p)
    p.add_argument("file", help="MCAP recording (a file cut short by a crash is replayed up to the cut)")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speed", type=float, default=1.0, help="time scale of the original timing (2 = twice as fast)")
    speed.add_argument("--fast", action="store_true", help="publish as fast as possible")
    p.add_argument(
        "--only", default=None, help="key expression to keep: relative to any session ('mocap/frame') or absolute"
    )
    # --session (from the bus flags) means "republish into this session"; unset keeps the recorded one.
    p.set_defaults(session=None)
    p.add_argument(
        "--keep-t0",
        action="store_true",
        help="publish headers with their recorded t0 (default: t0 = now, the time the message enters the bus "
        "again, so latency is measured and a running stack takes the replay as a restarted source)",
    )
    p.add_argument("--start-delay", type=float, default=0.5, help="wait for subscribers to be matched first [s]")


def main(args: argparse.Namespace) -> int:
    try:
        recording = read_recording(args.file)
        plan = ReplayPlan(None if args.fast else args.speed, args.only, args.session)
    except (OSError, ValueError, zenoh.ZError) as exc:
        log.error("%s", exc)
        return 2
    if args.session is None:
        first = next(iter(recording), None)
        args.session = (Keys.session_of(first.key) if first else None) or DEFAULT_SESSION
    late: list[float] = []
    n = 0
    with ServiceRunner("replay", args) as svc:
        pubs: dict[str, zenoh.Publisher] = {}
        # Matching routes need a moment after the publishers are declared; declare lazily but wait once.
        svc.stop_event.wait(args.start_delay)
        t_start = time.monotonic()
        for due in plan.plan(recording):
            if svc.stop_event.is_set():
                break
            pub = pubs.get(due.key)
            if pub is None:
                pub = pubs[due.key] = svc.session.declare_publisher(
                    due.key, congestion_control=zenoh.CongestionControl.BLOCK, express=True
                )
            # Re-stamped before the wait (t0 = the due wall-clock time), so the re-encoding does not
            # delay the publication itself.
            wait = t_start + due.offset - time.monotonic() if due.offset > 0 else 0.0
            data = due.data if args.keep_t0 else restamp(due.data, time.time_ns() + int(max(wait, 0.0) * 1e9))
            if due.offset > 0:
                wait = t_start + due.offset - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                late.append(max(0.0, time.monotonic() - t_start - due.offset))
            pub.put(data)
            svc.status.published("replay")
            n += 1
        elapsed = time.monotonic() - t_start
        for pub in pubs.values():
            pub.undeclare()
    late.sort()
    report = {
        "file": str(args.file),
        "published": n,
        "skipped": plan.skipped,
        "elapsed_s": round(elapsed, 4),
        "complete_file": recording.complete,
        "read_error": recording.error,
        "late_ms_p50": round(1e3 * late[len(late) // 2], 3) if late else 0.0,
        "late_ms_max": round(1e3 * late[-1], 3) if late else 0.0,
    }
    emit_json(report, indent=None)
    return 0
