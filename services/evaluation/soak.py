"""``python -m services.evaluation.soak``: the real stack under sustained mocap load.

Starts the router, retarget, solver and sim (and optionally the logger) as real
processes with the commands of docker-compose.yml, publishes HumanFrames of the
bundled demo motion at ``--rate`` Hz for ``--duration`` s from its own session,
and measures

* end-to-end latency per second of the run (first RobotState carrying a frame's
  ``seq`` minus the frame's ``hdr.t0``), so a latency that grows with time shows;
* the frames each service dropped (newest wins) from their ServiceStatus counts;
* every service's resident memory (``/proc/<pid>/status`` VmRSS) every
  ``--sample-period`` s: start, end, max and the least-squares slope [MB/min].

It prints one JSON report (also written to ``--json``). The stack is started by
:class:`~services.launcher.local_stack.LocalStack`; :class:`FramePublisher` is reused by
the fault injection tests (``tests/support/faults.py``).

Examples::

    python -m services.evaluation.soak --rate 1000 --duration 600 --json runs/soak.json
    python -m services.evaluation.soak --rate 10000 --duration 10 --json runs/burst.json
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from services.launcher.local_stack import LocalStack
from services.launcher.supervisor import rss_mb
from shared.bus import NumberedPublisher, free_port
from shared.keys import Keys
from shared.messages import SCHEMA_VERSION, HumanFrame, ServiceStatus, peek_header
from shared.report import emit_json

log = logging.getLogger("mimic.soak")
PIPELINE = ("retarget", "solver", "sim")


# --------------------------------------------------------------------------- observation


class _Arrivals:
    """First RobotState arrival [ns wall clock] per ``seq`` and every service's last status."""

    def __init__(self, z: zenoh.Session, keys: Keys):
        self.lock = threading.Lock()
        self.first_state_ns: dict[int, int] = {}
        self.status: dict[str, ServiceStatus] = {}
        self._subs = [
            z.declare_subscriber(keys.sim_state, self._on_state),
            z.declare_subscriber(keys.all_status, self._on_status),
        ]

    def _on_state(self, s: zenoh.Sample) -> None:
        now_ns = time.time_ns()
        hdr = peek_header(s.payload.to_bytes())
        if hdr is not None:
            with self.lock:
                self.first_state_ns.setdefault(hdr.seq, now_ns)

    def _on_status(self, s: zenoh.Sample) -> None:
        st = ServiceStatus.decode(s.payload.to_bytes())
        with self.lock:
            self.status[f"{st.service}/{st.instance}"] = st

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


# --------------------------------------------------------------------------- input


class FramePublisher:
    """Publishes the demo motion as HumanFrames at a fixed rate from a thread.

    The msgpack body of each clip frame is built once; per frame only the header
    (seq, stamp, t0) changes, so 10 kHz is reachable from Python.

    Args:
        z: an open zenoh session. keys: its session's keys. rate: frames per second [Hz].
    """

    def __init__(self, z: zenoh.Session, keys: Keys, rate: float):
        import msgpack

        from services.ingest.clip import load_clip
        from services.ingest.demo_motion import generate_demo_clips

        self._packb = msgpack.packb
        clip = load_clip(generate_demo_clips(tempfile.mkdtemp(prefix="mimic-soak-"))[0])
        self.fps = clip.fps
        self.bodies = []
        for i in range(clip.n_frames):
            d = {"v": SCHEMA_VERSION, "t": HumanFrame.TYPE}
            d.update(clip.frame(i, seq=0).body())
            self.bodies.append(d)
        self.rate = rate
        self.pub = NumberedPublisher(z, keys.mocap_frame)
        self.sent = 0
        self.late = 0
        self.t0_ns: dict[int, int] = {}
        self.t_start = 0.0
        self.t_end = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def publish_one(self, k: int) -> None:
        """Publish frame ``k`` (seq k, clip time k / rate) now."""
        d = self.bodies[int(k / self.rate * self.fps) % len(self.bodies)]
        t0 = time.time_ns()
        d["hdr"] = [k, k / self.rate, t0]
        self.pub.put(self._packb(d, use_bin_type=True))
        self.t0_ns[k] = t0
        self.sent = k + 1

    def run(self, duration: float, first: int = 0) -> None:
        """Publish frames ``first``, ``first`` + 1, ... for ``duration`` [s] (blocking), paced on monotonic time."""
        period = 1.0 / self.rate
        self.t_start = start = time.monotonic()
        n = first + int(duration * self.rate)
        k = first
        while k < n and not self._stop.is_set():
            target = start + (k - first) * period
            now = time.monotonic()
            if now < target:
                # Sleep, never spin: a busy-waiting publisher takes a core from the services.
                time.sleep(target - now)
                continue
            if now - target > 5 * period:
                self.late += 1
            self.publish_one(k)
            k += 1
        self.t_end = time.monotonic()

    def start(self, duration: float) -> None:
        self._thread = threading.Thread(target=self.run, args=(duration,), daemon=True)
        self._thread.start()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def stop(self) -> None:
        self._stop.set()
        self.join(5)

    @property
    def achieved_rate(self) -> float:
        return self.sent / max(self.t_end - self.t_start, 1e-9)


# --------------------------------------------------------------------------- figures


def latency_windows(t0_ns: dict[int, int], arrival_ns: dict[int, int], t_start_ns: int, window: float = 1.0):
    """End-to-end latency [ms] of the frames sent in each ``window`` [s] of the run.

    Returns:
        list of {"t_s", "sent", "reached", "p50", "p99", "max"} per window.
    """
    by_win: dict[int, list[float]] = {}
    sent: dict[int, int] = {}
    for seq, t0 in t0_ns.items():
        w = int((t0 - t_start_ns) / 1e9 / window)
        sent[w] = sent.get(w, 0) + 1
        if seq in arrival_ns:
            by_win.setdefault(w, []).append((arrival_ns[seq] - t0) / 1e6)
    out = []
    for w in sorted(sent):
        v = np.asarray(by_win.get(w, []))
        row = {"t_s": w * window, "sent": sent[w], "reached": int(v.size)}
        if v.size:
            row.update(p50=float(np.percentile(v, 50)), p99=float(np.percentile(v, 99)), max=float(v.max()))
        out.append(row)
    return out


def rss_summary(samples: list[tuple[float, float]], skip_s: float = 30.0) -> dict:
    """start/end/max RSS [MB] and the slope [MB/min] (least squares after ``skip_s`` of warm-up)."""
    if not samples:
        return {}
    t = np.array([s[0] for s in samples])
    m = np.array([s[1] for s in samples])
    use = t >= t[0] + skip_s
    if use.sum() < 3:
        use = np.ones_like(t, dtype=bool)
    slope = float(np.polyfit(t[use] / 60.0, m[use], 1)[0]) if use.sum() >= 2 else 0.0
    return {
        "start_mb": float(m[0]),
        "end_mb": float(m[-1]),
        "max_mb": float(m.max()),
        "slope_mb_per_min": slope,
        "fit_from_s": float(t[use][0] - t[0]),
        "samples": len(m),
    }


def dropped_counts(status: dict[str, ServiceStatus]) -> dict[str, dict[str, int]]:
    """Every ``dropped.*`` count of every service's last status."""
    return {
        name: {k: v for k, v in st.counts.items() if k.startswith("dropped")} for name, st in sorted(status.items())
    }


# --------------------------------------------------------------------------- command


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate", type=float, default=1000.0, help="mocap frames per second [Hz]")
    p.add_argument("--duration", type=float, default=600.0, help="seconds of publishing")
    p.add_argument("--sample-period", type=float, default=5.0, help="RSS sampling period [s]")
    p.add_argument("--warmup", type=float, default=30.0, help="seconds excluded from the RSS slope fit")
    p.add_argument("--logger", action="store_true", help="run the Rerun logger too (writes an .rrd in a temp dir)")
    p.add_argument("--algo", default=None, help="solver algorithm (default: the compose default)")
    p.add_argument("--json", default=None, help="write the report here too")


def run(args: argparse.Namespace) -> dict:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = f"soak{endpoint.rsplit(':', 1)[1]}"
    env = {"SOLVER": args.algo} if args.algo else {}
    names = [*PIPELINE, *(["logger"] if args.logger else [])]
    tmp = tempfile.mkdtemp(prefix="mimic-soak-")
    extra = {"logger": ["--rrd", str(Path(tmp) / "soak.rrd")]}
    rss: dict[str, list[tuple[float, float]]] = {}
    with LocalStack(session, endpoint, env=env, status_period=1.0) as stack:
        stack.start_all(names, extra)
        obs = _Arrivals(stack.bus, stack.keys)
        try:
            time.sleep(0.5)
            pub = FramePublisher(stack.bus, stack.keys, args.rate)
            t_start_ns = time.time_ns()
            t_start = time.monotonic()
            pub.start(args.duration)
            next_sample = t_start
            while True:
                now = time.monotonic()
                if now >= next_sample:
                    for n, pid in stack.pids().items():
                        v = rss_mb(pid)
                        if v is not None:
                            rss.setdefault(n, []).append((now - t_start, v))
                    next_sample += args.sample_period
                if now - t_start > args.duration:
                    break
                dead = [n for n in names if not stack.running(n)]
                if dead:
                    raise RuntimeError(f"services died during the soak: {dead}\n{stack.output()}")
                time.sleep(min(0.2, max(0.0, next_sample - now)))
            pub.join(30)
            time.sleep(1.0 + 2 * stack.status_period)
            with obs.lock:
                arrival = dict(obs.first_state_ns)
                status = dict(obs.status)
        finally:
            obs.close()
    windows = latency_windows(pub.t0_ns, arrival, t_start_ns)
    reached = sum(w["reached"] for w in windows)
    full = [w for w in windows if "p99" in w]
    return {
        "rate_hz": args.rate,
        "achieved_rate_hz": pub.achieved_rate,
        "duration_s": args.duration,
        "publisher_late_frames": pub.late,
        "sent": pub.sent,
        "reached_robot_state": reached,
        "latency_ms_first_s": full[0] if full else None,
        "latency_ms_last_s": full[-1] if full else None,
        "latency_ms_p99_max_over_windows": max((w["p99"] for w in full), default=None),
        "latency_windows": windows,
        "dropped": dropped_counts(status),
        "rss": {n: rss_summary(v, args.warmup) for n, v in sorted(rss.items())},
    }


def main(args: argparse.Namespace) -> int:
    res = run(args)
    emit_json(res, args.json)
    return 0


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    add_arguments(parser)
    sys.exit(main(parser.parse_args()))
