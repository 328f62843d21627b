"""Bus observer for the container tests: every state, command, status, liveliness change to JSONL.

Runs inside a container of the compose project (``observer`` in tests/docker/compose.test.yml),
so it sees the bus from inside the project's network, as the services do. The host-side test
reads the file while it grows: wall-clock times (``time.time()``) are comparable across
containers and the host, which share one kernel clock. One JSON object per line:

* ``{"k": "alive", "t", "e": "PUT"|"DELETE", "n": "service/instance"}``
* ``{"k": "state", "t", "seq", "t0", "q": [rad], "st": sim_time, "sid", "hold"}``
* ``{"k": "cmd", "t", "seq", "sid", "status", "q": [rad]}``: ``q`` only on the first
  :data:`CMD_Q_FIRST` commands after a pause of a solver id (a new solver) and every
  :data:`CMD_Q_EVERY` th, which keeps 500 Hz x several solvers cheap to write
* ``{"k": "frame", "t", "seq"}`` (mocap frames: seq only)
* ``{"k": "status", "t", "n", "state", "counts"}``

    python -m tests.docker.observe --out runs/SESSION_bus.jsonl   # MIMIC_CONNECT/MIMIC_SESSION or ZENOH_CONFIG
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
import time
from pathlib import Path

import zenoh

from shared.bus import ServiceRunner, add_bus_args, setup_logging
from shared.keys import Keys
from shared.messages import HumanFrame, JointCommand, RobotState, ServiceStatus

log = logging.getLogger("mimic.observe")
FLUSH_S = 0.05
#: A solver id silent this long [s] and then back is a new solver: its first commands carry q.
CMD_PAUSE_S = 0.05
CMD_Q_FIRST = 50
CMD_Q_EVERY = 25


class JsonlSink:
    """Thread-safe line buffer flushed to ``path`` every :data:`FLUSH_S`."""

    def __init__(self, path: Path):
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._f = path.open("a", buffering=1 << 16)
        self._lock = threading.Lock()
        self._lines: list[str] = []

    def add(self, rec: dict) -> None:
        line = json.dumps(rec, separators=(",", ":"))
        with self._lock:
            self._lines.append(line)

    def flush(self) -> None:
        with self._lock:
            lines, self._lines = self._lines, []
        if lines:
            self._f.write("\n".join(lines) + "\n")
            self._f.flush()

    def close(self) -> None:
        self.flush()
        self._f.close()


def _q(values) -> list[float]:
    return [round(float(v), 6) for v in values]


def observe(svc: ServiceRunner, sink: JsonlSink) -> None:
    """Declare the subscribers; samples go to ``sink`` until ``svc.stop_event``."""
    keys: Keys = svc.keys

    def guarded(fn):
        def cb(s: zenoh.Sample) -> None:
            try:
                fn(time.time(), s)
            except Exception as exc:  # a bad sample is logged, never fatal
                log.warning("%s: %s", s.key_expr, exc)

        return cb

    def on_state(t: float, s: zenoh.Sample) -> None:
        m = RobotState.decode(s.payload.to_bytes())
        sink.add(
            {
                "k": "state",
                "t": t,
                "seq": m.hdr.seq,
                "t0": m.hdr.t0,
                "q": _q(m.q),
                "st": m.sim_time,
                "sid": m.solver_id,
                "hold": m.holding,
            }
        )

    last_cmd: dict[str, list] = {}  # solver id -> [last arrival, commands since its (re)start]

    def on_cmd(t: float, s: zenoh.Sample) -> None:
        m = JointCommand.decode(s.payload.to_bytes())
        last = last_cmd.setdefault(m.solver_id, [0.0, 0])
        last[1] = 0 if t - last[0] > CMD_PAUSE_S else last[1] + 1
        last[0] = t
        rec = {"k": "cmd", "t": t, "seq": m.hdr.seq, "sid": m.solver_id, "status": m.status}
        if last[1] < CMD_Q_FIRST or last[1] % CMD_Q_EVERY == 0:
            rec["q"] = _q(m.q)
        sink.add(rec)

    def on_frame(t: float, s: zenoh.Sample) -> None:
        m = HumanFrame.decode(s.payload.to_bytes())
        sink.add({"k": "frame", "t": t, "seq": m.hdr.seq})

    def on_status(t: float, s: zenoh.Sample) -> None:
        m = ServiceStatus.decode(s.payload.to_bytes())
        sink.add({"k": "status", "t": t, "n": f"{m.service}/{m.instance}", "state": m.state, "counts": m.counts})

    def on_alive(t: float, s: zenoh.Sample) -> None:
        parsed = Keys.parse_alive(str(s.key_expr))
        if parsed is not None:
            kind = "DELETE" if s.kind == zenoh.SampleKind.DELETE else "PUT"
            sink.add({"k": "alive", "t": t, "e": kind, "n": "/".join(parsed)})

    z = svc.session
    subs = [
        z.declare_subscriber(keys.sim_state, guarded(on_state)),
        z.declare_subscriber(keys.all_commands, guarded(on_cmd)),
        z.declare_subscriber(keys.mocap_frame, guarded(on_frame)),
        z.declare_subscriber(keys.all_status, guarded(on_status)),
        z.liveliness().declare_subscriber(keys.all_alive, guarded(on_alive), history=True),
    ]
    sink.add({"k": "ready", "t": time.time()})
    while not svc.stop_event.wait(FLUSH_S):
        sink.flush()
    for sub in subs:
        sub.undeclare()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    p.add_argument("--out", type=Path, required=True, help="JSONL file (appended)")
    p.add_argument("--instance", default="observer", help="liveliness instance name")
    add_bus_args(p)
    args = p.parse_args()
    setup_logging()
    sink = JsonlSink(args.out)
    try:
        # Recorder: a known identity under deploy/secure (it may read mimic/**, publish nothing but its own status).
        with ServiceRunner("recorder", args, instance=args.instance) as svc:
            observe(svc, sink)
    finally:
        sink.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
