"""``mimic bench handoff``: what one bus hand-off costs, per delivery mechanism.

One process, a Zenoh router on a free loopback port and two sessions: a publisher
thread puts small payloads at ``--rate`` Hz carrying ``perf_counter_ns()``; the
receiving side hands each one to a worker thread that busy-works ``--work-ms`` per
message (holding the GIL, like a service's step). Latency is worker receipt minus
put, on one clock. Mechanisms compared:

* ``ring_slot``: :func:`~shared.bus.ring_pump` (Zenoh's ``RingChannel``, drained in
  batches by a thread) -> :class:`~shared.bus.LatestSlot` -> worker ``take(timeout)``:
  what the services use.
* ``callback_slot``: Zenoh callback -> LatestSlot -> worker: what the services used
  before (the Zenoh thread needs the GIL for every sample).
* ``ring_channel``: the worker blocking in the ring's ``recv()`` itself (no timeout,
  so a worker with deadlines cannot wait on it).
* ``inline``: the work done in the Zenoh callback itself (no hand-off; a lower bound).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import struct
import sys
import threading
import time

import numpy as np
import zenoh

from shared.bus import LatestSlot, StatusCounters, free_port, ring_pump
from shared.report import emit_json

log = logging.getLogger("mimic.bench.handoff")
MECHANISMS = ("ring_slot", "callback_slot", "ring_channel", "inline")
_STAMP = struct.Struct("<qq")  # (index, perf_counter_ns at put)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate", type=float, default=1000.0, help="messages per second [Hz]")
    p.add_argument("--count", type=int, default=3000, help="messages per mechanism")
    p.add_argument("--work-ms", type=float, default=0.1, help="busy work per message in the worker [ms]")
    p.add_argument("--switch-ms", type=float, default=0.5, help="sys.setswitchinterval [ms]")
    p.add_argument(
        "--mechanisms", default=",".join(MECHANISMS), help="comma-separated subset of " + ",".join(MECHANISMS)
    )
    p.add_argument("--json", default=None, help="write the result here as JSON (also printed)")


def _session(endpoint: str, mode: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints" if mode == "router" else "connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(conf)


def _busy(ms: float) -> None:
    end = time.perf_counter() + ms / 1e3
    while time.perf_counter() < end:
        pass


def _measure(mechanism: str, endpoint: str, args: argparse.Namespace) -> dict:
    """Latencies [ms] of ``args.count`` messages through ``mechanism``."""
    rx, tx = _session(endpoint, "client"), _session(endpoint, "client")
    key = f"handoff/{mechanism}"
    lat: dict[int, int] = {}
    done = threading.Event()

    def record(raw: bytes) -> None:
        i, t = _STAMP.unpack(raw)
        lat[i] = time.perf_counter_ns() - t
        _busy(args.work_ms)
        if i == args.count - 1:
            done.set()

    entities = []
    worker = None
    status = StatusCounters("bench", "handoff", log)
    if mechanism == "inline":
        entities.append(rx.declare_subscriber(key, lambda s: record(s.payload.to_bytes())))
    elif mechanism in ("callback_slot", "ring_slot"):
        slot = LatestSlot(status, "x", depth=32)
        if mechanism == "ring_slot":  # not undeclared: closing the session ends the pump
            ring_pump(rx, key, 32, lambda s: slot.put(s.payload.to_bytes()), status, "bench")
        else:
            entities.append(rx.declare_subscriber(key, lambda s: slot.put(s.payload.to_bytes())))

        def spin() -> None:
            while not done.is_set():
                raw = slot.take(timeout=0.1)
                if raw is not None:
                    record(raw)

        worker = threading.Thread(target=spin, daemon=True)
    else:
        sub = rx.declare_subscriber(key, zenoh.handlers.RingChannel(32))
        entities.append(sub)

        def spin() -> None:
            while not done.is_set():
                try:
                    record(sub.recv().payload.to_bytes())
                except Exception:  # undeclared: the channel is closed
                    return

        worker = threading.Thread(target=spin, daemon=True)
    if worker is not None:
        worker.start()
    pub = tx.declare_publisher(key, express=True)
    time.sleep(0.5)  # let the subscription propagate
    period = 1.0 / args.rate
    start = time.monotonic()
    for i in range(args.count):
        delay = start + i * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        pub.put(_STAMP.pack(i, time.perf_counter_ns()))
    done.wait(2.0)
    for e in (pub, *entities):
        e.undeclare()
    rx.close()
    tx.close()
    ms = np.asarray(list(lat.values()), dtype=float) / 1e6
    if ms.size == 0:
        return {"received": 0}
    return {
        "received": int(ms.size),
        # Not received by the worker: overflowed the 32-deep mailbox (counted, the two slot mechanisms),
        # lost in Zenoh or the ring (invisible), or still queued after the 2 s grace.
        "lost": args.count - int(ms.size),
        "mailbox_dropped": status.count("dropped"),
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
    }


def run(args: argparse.Namespace) -> dict:
    sys.setswitchinterval(args.switch_ms / 1e3)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    result: dict = {
        "load_avg_1m": os.getloadavg()[0],
        "rate_hz": args.rate,
        "count": args.count,
        "work_ms": args.work_ms,
        "switch_ms": args.switch_ms,
    }
    with _session(endpoint, "router"):
        for m in args.mechanisms.split(","):
            if m not in MECHANISMS:
                raise SystemExit(f"unknown mechanism {m!r}; known: {', '.join(MECHANISMS)}")
            result[m] = _measure(m, endpoint, args)
    return result


def main(args: argparse.Namespace) -> int:
    emit_json(run(args), args.json)
    return 0
