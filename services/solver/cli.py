"""``mimic solve``: the solver service."""

from __future__ import annotations

import argparse

from services.solver.qp import QP_BACKENDS
from services.solver.registry import ALGORITHMS
from shared.bus import add_bus_args
from shared.robot.profile import DEFAULT_PROFILE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``mimic solve``."""
    parser.add_argument("--algo", choices=sorted(ALGORITHMS), default="hqp-nullspace", help="solver algorithm")
    parser.add_argument("--qp", choices=sorted(QP_BACKENDS), default="piqp", help="QP backend")
    parser.add_argument("--id", default="main", help="solver id: commands go to mimic/<session>/solver/<id>/command")
    parser.add_argument("--rate", type=float, default=500.0, help="control rate [Hz]")
    parser.add_argument("--no-waist", action="store_true", help="control the 14 arm joints only")
    parser.add_argument("--robot", default=None, help=f"robot profile name or TOML path (default {DEFAULT_PROFILE})")
    parser.add_argument("--no-smoothing", action="store_true", help="publish raw solver output (no quintic)")
    parser.add_argument(
        "--orientation-weight", type=float, default=None, help="wrist orientation cost [1/rad] (default: SolverConfig)"
    )
    parser.add_argument("--gain", type=float, default=None, help="task error gain [1/s] (default: SolverConfig)")
    parser.add_argument(
        "--orientation-gain",
        type=float,
        default=None,
        help="wrist orientation error gain [1/s] when orientations are not on level 1 (default: SolverConfig)",
    )
    parser.add_argument(
        "--wrist-orientation-level",
        type=int,
        choices=(1, 2, 3),
        default=None,
        help="1: the paper's hierarchy (wrist poses > elbows > posture); 2 (default): wrist positions > "
        "elbows + wrist orientations > posture; 3: wrist positions > elbows > wrist orientations",
    )
    parser.add_argument(
        "--closed-loop",
        action="store_true",
        help="re-anchor on the measured joints when they drift more than the resync threshold from the command",
    )
    parser.add_argument(
        "--trigger",
        choices=("rate", "event"),
        default="rate",
        help="rate: tick on the fixed clock only; event: also tick as soon as new targets arrive "
        "(lowest latency; meant for mocap at or above the control rate)",
    )
    parser.add_argument(
        "--startup-wait", type=float, default=0.5, help="wait this long [s] for a robot state to start from"
    )
    add_bus_args(parser)


def main(args: argparse.Namespace) -> int:
    """Run the solver service."""
    from services.solver.node import run

    return run(args)
