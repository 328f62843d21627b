"""``mimic bench <what>``: every benchmark, each printing JSON anyone can rerun.

Each bench module provides ``add_arguments(parser)`` and ``main(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib

#: bench name -> (module, one-line help)
BENCHES = {
    "solvers": ("services.solver.bench", "per-tick time of every algorithm with PIQP and DAQP, beside mink"),
    "pipeline": ("services.evaluation.pipeline_bench", "the real stack on loopback at a fixed mocap rate"),
    "handoff": (
        "services.evaluation.handoff_bench",
        "one bus hand-off per delivery mechanism (ring+slot as shipped, callback, ring, inline)",
    ),
    "logger": ("services.logger.bench_cli", "logger throughput: bus messages per second its core takes"),
    "recorder": ("services.recorder.bench_cli", "recorder loss and memory: N messages at R Hz through a router"),
    "ingest": ("services.ingest.bench", "clips loaded, parse speed, the error a broken file gives"),
    "retarget": ("services.retarget.bench", "retargeting figures per mapping mode over the real clips"),
    "sim-track": ("services.sim.tracking_cli", "servo tracking of a sine in the MuJoCo sim"),
    "posture": ("services.posture.bench", "numpy posture-policy inference per control tick, both arms"),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    for name, (module, help_text) in BENCHES.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(module).add_arguments(sp)


def main(args: argparse.Namespace) -> int:
    return int(importlib.import_module(BENCHES[args.bench][0]).main(args) or 0)
