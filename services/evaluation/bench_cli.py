"""``mimic bench {solvers,pipeline}``: benchmarks that print JSON anyone can rerun."""

from __future__ import annotations

import argparse
import importlib

BENCHES = {
    "solvers": ("services.solver.bench", "per-tick time of every algorithm with PIQP and DAQP, beside mink"),
    "pipeline": ("services.evaluation.pipeline_bench", "the real stack on loopback at a fixed mocap rate"),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    for name, (module, help_text) in BENCHES.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(module).add_arguments(sp)


def main(args: argparse.Namespace) -> int:
    return int(importlib.import_module(BENCHES[args.bench][0]).main(args) or 0)
