"""``mimic bench pipeline``: the real stack on loopback, driven at a fixed mocap rate.

It starts the router, retarget, solver and sim as real processes (the same
commands ``mimic up`` takes from docker-compose.yml), publishes HumanFrames at
``--rate`` Hz for ``--duration`` seconds from its own session, and timestamps
the first arrival of each ``seq`` at every hop (targets, command, robot
state) on one clock. Latency is ``arrival - hdr.t0``; a frame is dropped at a
hop when its ``seq`` never shows up there.

As issue 13 specifies the bench, the solver ticks on every target (``--trigger event``,
with ``--rate`` the input rate up to the shipped 500 Hz: :func:`solver_rate`)
and the sim publishes a state right after each applied command (``--state-on-command``:
states at the input rate; the ``--state-rate`` ones only fill pauses), so the last hop's
arrival is "command applied in the sim". ``hop_ms`` is each service's increment (its output's arrival minus its input's
arrival; for retarget, minus ``t0``): one bus hop plus the service's hand-off and work.
``drops`` says where frames were lost: each service's own mailbox drops (``dropped``)
and the samples it never received (``gaps``: numbers skipped by its publishers, i.e.
lost inside Zenoh), per input stream; ``drops_total`` sums them over the frame's path
(frames, targets, commands: not the solver's newest-wins ``sim_state`` feedback).
``cpu_ms_per_frame`` is each process's CPU time over the measured frames per frame sent: where
the time goes, whatever else the machine runs (latency and drops depend on that);
``cpu_ms_per_frame_by_thread`` splits it into Zenoh's runtime threads and the interpreter's, and
``idle_cpu_ms_per_s`` is what each process burns in the second before the first frame.

``--noop`` measures the floor under all of this: no-work stand-ins (:mod:`services.evaluation.relay`)
replace retarget, solver and sim, each still its own process decoding the real input and
publishing the real output type on the real keys, so what remains is the bus and the processes.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from services.evaluation.relay import DELIVERIES
from services.launcher.local_stack import LocalStack
from services.launcher.stack import ROUTER_SERVICE
from shared.bus import NumberedPublisher, StatusCounters, free_port, gap_watch
from shared.messages import ServiceStatus, peek_header
from shared.report import emit_json

log = logging.getLogger("mimic.bench.pipeline")
HOPS = ("retarget", "solver", "sim")
#: Input streams on a frame's path (mocap -> targets -> command); ``sim_state`` into the solver is
#: feedback, newest-wins by design, and its overwritten samples are not lost frames.
PATH = ("frames", "targets", "commands")
#: ServiceStatus period of the bench's services [s]: the last one must come after the last frame.
STATUS_PERIOD_S = 0.25
#: Seconds between the services being up and the first frame; their CPU time then is ``idle_cpu_ms_per_s``.
IDLE_WINDOW_S = 1.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate", type=float, default=1000.0, help="mocap frames per second [Hz]")
    p.add_argument("--duration", type=float, default=10.0, help="seconds of publishing")
    p.add_argument("--json", default=None, help="write the result here as JSON (also printed)")
    p.add_argument("--port", type=int, default=0, help="router port (default: a free one)")
    p.add_argument("--algo", default="hqp-nullspace")
    p.add_argument(
        "--solver-args", default="", help="extra solver flags, e.g. '--qp daqp' (after the bench's '--trigger event')"
    )
    p.add_argument("--sim-args", default="", help="extra sim flags (after the bench's '--state-on-command')")
    p.add_argument("--warmup", type=float, default=1.0, help="seconds of frames before measuring")
    p.add_argument(
        "--noop",
        action="store_true",
        help="the bus floor: no-work stand-ins (services/evaluation/relay.py) instead of retarget, solver, sim",
    )
    p.add_argument(
        "--delivery",
        choices=DELIVERIES,
        default="shipped",
        help="--noop: how a sample reaches each stand-in's worker (shipped: the services' wiring)",
    )
    p.add_argument("--relay-args", default="", help="--noop: extra stand-in flags, e.g. '--depth 4'")


class _Arrivals:
    """First arrival time [ns] of each seq at one hop, plus the seq's t0."""

    def __init__(self) -> None:
        self.first: dict[int, int] = {}
        self.lock = threading.Lock()

    def add(self, seq: int, now: int) -> None:
        with self.lock:
            self.first.setdefault(seq, now)


def _frames(n_frames: int, rate: float):
    """HumanFrame factory from the bundled demo motion, resampled to ``rate``."""
    from services.ingest.clip import load_clip
    from services.ingest.demo_motion import generate_demo_clips

    out = Path(tempfile.mkdtemp(prefix="mimic-bench-"))
    clip = load_clip(generate_demo_clips(out)[0])
    idx = (np.arange(n_frames) / rate * clip.fps).astype(int) % clip.n_frames
    return clip, idx


def _stat_cpu(path: Path) -> tuple[str, float] | None:
    """(name, CPU time [s] user + system) from a /proc ``stat`` file of a process or thread; None if unreadable."""
    try:
        name, rest = path.read_text().split("(", 1)[1].rsplit(")", 1)
        fields = rest.split()
        return name, (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def cpu_seconds(pid: int) -> float | None:
    """CPU time [s] (user + system) a process has used so far; None where /proc cannot say."""
    got = _stat_cpu(Path(f"/proc/{pid}/stat"))
    return None if got is None else got[1]


def thread_cpu_seconds(pid: int) -> dict[str, float]:
    """CPU time [s] a process's threads have used so far, summed per thread name with its ``-N`` suffix cut.

    Zenoh's runtimes name their threads (``rx-0``, ``tx-1``, ``app-0``, ``net-0``, ``acc-0``: receiving,
    sending, ...); every Python thread has the process's name (``python``), so the split tells the bus
    runtime's share from the interpreter's. Python callbacks run on Zenoh's ``rx`` threads and count there.
    Threads that already ended are missing; empty where /proc cannot say.
    """
    out: dict[str, float] = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        got = _stat_cpu(Path(f"/proc/{pid}/task/{tid}/stat"))
        if got is None:
            continue
        stem, _, suffix = got[0].rpartition("-")
        group = stem if stem and suffix.isdigit() else got[0]
        out[group] = out.get(group, 0.0) + got[1]
    return out


def solver_rate(input_rate: float) -> float:
    """The bench solver's ``--rate`` [Hz]: the input rate, at most the shipped control rate.

    ``--trigger event`` is meant for mocap at or above the control rate (``mimic solve --help``):
    every tick then has new targets. Below it (200 Hz mocap on the 500 Hz default) the clock adds
    ticks between targets, 2-3 per frame, each one a command, a sim state and a solver state decode
    more, which on 2 cores turned into queueing on every hop.
    """
    from services.solver.core import SolverConfig

    return min(float(input_rate), SolverConfig().rate)


def start_relays(stack: LocalStack, rate: float, delivery: str, extra: str = "", timeout: float = 90.0) -> None:
    """The ``--noop`` stand-ins (:mod:`services.evaluation.relay`) in place of retarget, solver and sim.

    Same router, session, environment and status period as the services (their ServiceRunner names
    too), so everything the bench reads about them is read the same way.
    """
    for h in HOPS:
        argv = [sys.executable, "-m", "services.evaluation.relay", h, "--delivery", delivery]
        argv += ["--rate", f"{solver_rate(rate):g}", "--status-period", str(STATUS_PERIOD_S), *extra.split()]
        stack.start(h, argv=argv, env=stack.command(h)[1])
    stack.wait_alive(HOPS, timeout)


def run(args: argparse.Namespace) -> dict:
    noop = bool(getattr(args, "noop", False))
    port = args.port or free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    extra = {
        "solver": ["--trigger", "event", "--rate", f"{solver_rate(args.rate):g}", *args.solver_args.split()],
        "sim": ["--state-on-command", *args.sim_args.split()],
    }
    n_total = int((args.duration + args.warmup) * args.rate)
    clip, idx = _frames(n_total, args.rate)
    arrivals = {h: _Arrivals() for h in HOPS}
    statuses: dict[str, ServiceStatus] = {}
    observer = StatusCounters("bench", "observer", log)
    with LocalStack(f"bench{port}", endpoint, env={"SOLVER": args.algo}, status_period=STATUS_PERIOD_S) as stack:
        stack.start_router()
        z, keys = stack.bus, stack.keys

        def hop(name: str):
            # Header only: full validation of every message at every hop would cost the
            # observer a good part of a core that the 2-core machine's services need.
            watch = gap_watch(observer, name)

            def cb(sample: zenoh.Sample) -> None:
                now = time.time_ns()
                watch(sample)
                hdr = peek_header(sample.payload.to_bytes())
                if hdr is not None:
                    arrivals[name].add(hdr.seq, now)

            return cb

        subs = [
            z.declare_subscriber(keys.targets, hop("retarget")),
            z.declare_subscriber(keys.command("main"), hop("solver")),
            z.declare_subscriber(keys.sim_state, hop("sim")),
            z.declare_subscriber(
                keys.all_status,
                lambda s: statuses.__setitem__(str(s.key_expr), ServiceStatus.decode(s.payload.to_bytes())),
            ),
        ]
        if noop:
            start_relays(stack, args.rate, args.delivery, getattr(args, "relay_args", ""))
        else:
            stack.start_all(HOPS, extra, timeout=90)
        pids = {**{h: stack.pid(h) for h in HOPS}, "router": stack.pid(ROUTER_SERVICE), "bench": os.getpid()}
        # Before any frame: what each process burns on its own (Zenoh runtime, status, idle ticks).
        idle0 = {h: cpu_seconds(p) if p else None for h, p in pids.items()}
        time.sleep(IDLE_WINDOW_S)
        idle1 = {h: cpu_seconds(p) if p else None for h, p in pids.items()}
        pub = NumberedPublisher(z, keys.mocap_frame)
        t0_pub: dict[int, int] = {}
        period = 1.0 / args.rate
        start = time.monotonic()
        late = 0
        frames = {i: clip.frame(int(i), seq=0) for i in np.unique(idx)}
        first = int(args.warmup * args.rate)
        cpu0: dict[str, float | None] = {}
        threads0: dict[str, dict[str, float]] = {}
        for k in range(n_total):
            if k == first:  # CPU over the measured frames only (start-up and warm-up left out)
                cpu0 = {h: cpu_seconds(p) if p else None for h, p in pids.items()}
                threads0 = {h: thread_cpu_seconds(p) for h, p in pids.items() if p}
            target = start + k * period
            now = time.monotonic()
            # Sleep, never spin: a busy-waiting publisher takes a whole core from the services.
            if target > now:
                time.sleep(target - now)
                now = time.monotonic()
            if now - target > 5 * period:
                late += 1
            frame = frames[int(idx[k])]
            frame.hdr.seq = k
            frame.hdr.stamp = k * period
            t0_pub[k] = frame.hdr.t0 = time.time_ns()
            pub.put(frame.encode())
        elapsed = time.monotonic() - start
        cpu1 = {h: cpu_seconds(p) if p else None for h, p in pids.items()}
        threads1 = {h: thread_cpu_seconds(p) for h, p in pids.items() if p}
        time.sleep(1.5 + 2 * STATUS_PERIOD_S)
        pub.undeclare()
        for s in subs:
            s.undeclare()

    measured = range(first, n_total)
    result: dict = {
        "load_avg_1m": os.getloadavg()[0],
        "rate_hz": args.rate,
        "achieved_rate_hz": n_total / elapsed,
        "publisher_late_frames": late,
        "sent": len(measured),
        "algo": None if noop else args.algo,
        "noop": noop,
        "delivery": args.delivery if noop else None,
    }
    lat_ms: dict[str, list[float]] = {}
    dropped: dict[str, int] = {}
    for h in HOPS:
        got = arrivals[h].first
        lat_ms[h] = [(got[s] - t0_pub[s]) / 1e6 for s in measured if s in got]
        dropped[h] = sum(1 for s in measured if s not in got)
    e2e = lat_ms["sim"]
    result["received"] = len(e2e)
    result["dropped"] = dropped

    def pct(v: list[float]) -> dict:
        if not v:
            return {"p50": None, "p99": None, "max": None}
        return {"p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)), "max": float(np.max(v))}

    result["latency_ms"] = pct(e2e)
    result["hop_latency_ms"] = {h: pct(v) for h, v in lat_ms.items()}
    # Per-hop increments: where the time goes.
    inc = {}
    prev = None
    for h in HOPS:
        if prev is None:
            inc[h] = result["hop_latency_ms"][h]
        else:
            both = [s for s in measured if s in arrivals[h].first and s in arrivals[prev].first]
            inc[h] = pct([(arrivals[h].first[s] - arrivals[prev].first[s]) / 1e6 for s in both])
        prev = h
    result["hop_increment_ms"] = inc
    result["hop_ms"] = {h: {"p50": v["p50"], "p99": v["p99"]} for h, v in inc.items()}
    result["drops"] = service_drops(statuses)
    result["drops_total"] = path_drops(result["drops"])
    result["observer_gaps"] = observer.count("gaps")
    # Where the time goes, independent of how busy the machine is: each process's CPU time per frame
    # sent over the measured frames (the bench: encoding, publishing and observing them).
    n_measured = max(1, len(measured))
    result["cpu_ms_per_frame"] = {
        h: None if cpu0.get(h) is None or cpu1[h] is None else (cpu1[h] - cpu0[h]) * 1e3 / n_measured for h in pids
    }
    # The same per thread group (see thread_cpu_seconds): Zenoh's runtime against the interpreter.
    result["cpu_ms_per_frame_by_thread"] = {
        h: {
            g: round((t1 - threads0.get(h, {}).get(g, 0.0)) * 1e3 / n_measured, 4)
            for g, t1 in sorted(threads1[h].items())
        }
        for h in threads1
    }
    result["idle_cpu_ms_per_s"] = {
        h: None if idle0[h] is None or idle1[h] is None else (idle1[h] - idle0[h]) * 1e3 / IDLE_WINDOW_S for h in pids
    }
    result["service_status"] = {
        k: {"counts": v.counts, "rejects": v.rejects, "extra": v.extra} for k, v in statuses.items()
    }
    return result


def service_drops(statuses: dict[str, ServiceStatus]) -> dict[str, dict[str, dict[str, int]]]:
    """Per service, per input stream: mailbox ``dropped`` and Zenoh-lost ``gaps`` (from the last statuses)."""
    out: dict[str, dict[str, dict[str, int]]] = {}
    for st in statuses.values():
        name = st.service if st.instance == "main" else f"{st.service}/{st.instance}"
        out[name] = {
            kind: {k.split(".", 1)[1]: int(n) for k, n in st.counts.items() if k.startswith(kind + ".")}
            for kind in ("dropped", "gaps")
        }
    return out


def path_drops(drops: dict[str, dict[str, dict[str, int]]]) -> int:
    """Frames lost on the frame's path (:data:`PATH` streams), mailbox drops and gaps, over all services."""
    return sum(n for d in drops.values() for kind in ("dropped", "gaps") for s, n in d[kind].items() if s in PATH)


def main(args: argparse.Namespace) -> int:
    res = run(args)
    emit_json(res, args.json)
    return 0
