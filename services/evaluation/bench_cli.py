"""``mimic bench <what>``: every benchmark, each printing JSON anyone can rerun.

The benchmarks are the ``bench`` table of ``services/commands.toml``; each module provides
``add_arguments(parser)`` and ``main(args) -> int``.
"""

from __future__ import annotations

import argparse

from services.commands import add_subcommands, run


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_subcommands(p, "bench", "bench", "BENCH", required=True)


def main(args: argparse.Namespace) -> int:
    return run("bench", args.bench, args)
