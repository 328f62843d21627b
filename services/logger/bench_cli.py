"""``mimic bench logger``: how many bus messages per second the logger's core can take.

Builds the message mix of a running stack for ``--frames`` mocap frames at
``--source-rate`` (per frame: one HumanFrame, one TaskTargets, one JointCommand per
solver, ``--states-per-frame`` RobotStates from a real MuJoCo sim), runs every
payload through :meth:`RerunLogger.step` into a temporary ``.rrd`` and prints JSON:
per-type p50/p99 step time [us], overall messages per second, decimated counts.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from services.logger.config import LoggerConfig
from shared.config import add_dataclass_arguments, config_from_args

log = logging.getLogger("mimic.bench")


@dataclass(frozen=True)
class BenchTraffic:
    """The synthetic bus traffic the bench runs through the logger.

    Attributes:
        frames: mocap frames.
        source_rate: mocap rate [Hz] (stamps).
        solvers: solvers publishing commands.
        states_per_frame: RobotStates per frame (200 Hz sim: 2).
    """

    frames: int = 300
    source_rate: float = 100.0
    solvers: int = 1
    states_per_frame: int = 2

    def __post_init__(self) -> None:
        if self.frames < 1 or self.solvers < 0 or self.states_per_frame < 0 or not self.source_rate > 0:
            raise ValueError("frames must be >= 1, solvers and states_per_frame >= 0, source_rate > 0 Hz")


#: The LoggerConfig fields the bench varies (the shipped defaults otherwise).
LOGGER_FIELDS = ("meshes", "robot_rate", "skeleton_rate")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_dataclass_arguments(p, BenchTraffic)
    add_dataclass_arguments(p, LoggerConfig, only=LOGGER_FIELDS)


def synthetic_stream(frames: int, source_rate: float, solvers: int, states_per_frame: int) -> list[bytes]:
    """Encoded payloads in bus order (real sim states, random operator)."""
    from services.sim.sim_core import SimConfig, SimCore
    from shared.messages import (
        HUMAN_BONES,
        TARGET_NAMES,
        Bone,
        Header,
        HumanFrame,
        JointCommand,
        Pose,
        Target,
        TaskTargets,
    )

    core = SimCore(config=SimConfig(watchdog=1.0))
    rng = np.random.default_rng(0)
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    dt = 1.0 / source_rate
    out = []
    for k in range(frames):
        hdr = Header(k, k * dt)
        bones = {b: Bone(rng.normal(0, 0.3, 3), ident) for b in HUMAN_BONES}
        out.append(HumanFrame(hdr, "bench", Pose(np.zeros(3), ident), bones).encode())
        fr = core.state().frames
        targets = {t: Target(fr[t].p, fr[t].q, np.zeros(3), np.zeros(3)) for t in TARGET_NAMES}
        out.append(TaskTargets(hdr, targets).encode())
        q = core.q + rng.normal(0, 0.01, core.q.shape)
        for s in range(solvers):
            cmd = JointCommand(
                hdr, f"s{s}" if s else "main", "hqp", list(core.joint_names), q, 0 * q, [1e-3, 1e-2], 0.2
            )
            out.append(cmd.encode())
            if s == 0:
                core.apply(cmd)
        for _ in range(states_per_frame):
            core.step_physics(max(1, round(dt / states_per_frame / core.dt)))
            out.append(core.state().encode())
    return out


def main(args: argparse.Namespace) -> int:
    import rerun as rr

    from services.logger.rerun_logger import RerunLogger
    from services.logger.robot_visual import RobotVisual
    from shared.messages import peek_type

    try:
        traffic = config_from_args(BenchTraffic, args)
        lc = config_from_args(LoggerConfig, args)
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    payloads = synthetic_stream(traffic.frames, traffic.source_rate, traffic.solvers, traffic.states_per_frame)
    with tempfile.TemporaryDirectory() as tmp:
        rrd = Path(tmp) / "bench.rrd"
        rec = rr.RecordingStream("mimic_bench")
        rec.save(str(rrd))
        visual = RobotVisual() if lc.meshes else None
        lg = RerunLogger(rec, visual, robot_rate=lc.robot_rate, skeleton_rate=lc.skeleton_rate)
        lg.setup()
        times: dict[str, list[float]] = {}
        t_all = time.perf_counter()
        for p in payloads:
            kind = peek_type(p) or "?"
            t = time.perf_counter()
            lg.step("bench", p)
            times.setdefault(kind, []).append((time.perf_counter() - t) * 1e6)
        total = time.perf_counter() - t_all
        rec.flush()
        rec.disconnect()
        size = rrd.stat().st_size
    source_s = traffic.frames / traffic.source_rate
    out = {
        "messages": len(payloads),
        "bus_rate_hz": round(len(payloads) / source_s, 1),
        "logger_msgs_per_s": round(len(payloads) / total, 1),
        "cpu_fraction_at_bus_rate": round(total / source_s, 3),
        "step_us": {
            k: {"n": len(v), "p50": round(float(np.percentile(v, 50)), 1), "p99": round(float(np.percentile(v, 99)), 1)}
            for k, v in times.items()
        },
        "counts": lg.counts,
        "rrd_bytes": size,
        "meshes": visual is not None,
        "robot_rate_hz": lc.robot_rate,
        "skeleton_rate_hz": lc.skeleton_rate,
    }
    json.dump(out, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    sys.exit(main(parser.parse_args()))
