"""``mimic solve``: the solver service.

Flags of the solver's settings are built from :class:`~services.solver.core.SolverConfig`
(:func:`shared.config.add_dataclass_arguments`): defaults, units and validation live there.
"""

from __future__ import annotations

import argparse
import logging

from services.solver.core import SATURATION_TRIGGERS, SolverConfig
from services.solver.qp import QP_BACKENDS
from services.solver.registry import ALGORITHMS
from shared.bus import add_bus_args
from shared.config import add_dataclass_arguments
from shared.robot.profile import DEFAULT_PROFILE

log = logging.getLogger("mimic.solver")

#: Flag names that differ from the SolverConfig field names, and choices for the text fields.
FLAGS = {
    "algo": {"choices": sorted(ALGORITHMS)},
    "qp": {"choices": sorted(QP_BACKENDS)},
    "solver_id": {"flag": "--id", "help": "solver id: commands go to mimic/<session>/solver/<id>/command"},
    "wrist_orientation_cost": {"flag": "--orientation-weight"},
    "wrist_orientation_level": {"choices": (1, 2, 3)},
    "posture_policy": {"metavar": "FILE"},
    "saturation_trigger": {"choices": SATURATION_TRIGGERS},
}


def add_self_collision_choice(parser: argparse.ArgumentParser) -> None:
    """``--self-collision on|off`` for the commands that build their own solver (``mimic eval``, ``mimic bench
    solvers``), so an on/off comparison runs in one tree; read it back with :func:`self_collision_choice`."""
    parser.add_argument(
        "--self-collision",
        choices=("on", "off"),
        default=None,
        help="the solver's self-collision damper rows on or off (default: SolverConfig's, as shipped)",
    )


def self_collision_choice(args: argparse.Namespace) -> bool | None:
    """``--self-collision`` as a ``SolverConfig.self_collision`` value (None: not given, keep the default)."""
    choice = getattr(args, "self_collision", None)
    return None if choice is None else choice == "on"


def add_trunk_projection_choice(parser: argparse.ArgumentParser) -> None:
    """``--trunk-projection on|off`` for the commands that build their own solver (``mimic eval``, ``mimic bench
    solvers``); read it back with :func:`trunk_projection_choice`."""
    parser.add_argument(
        "--trunk-projection",
        choices=("on", "off"),
        default=None,
        help="move wrist targets inside the waist-carried trunk onto its surface, where the waist holds it now "
        "(SolverConfig.trunk_projection; default: SolverConfig's, as shipped)",
    )


def trunk_projection_choice(args: argparse.Namespace) -> bool | None:
    """``--trunk-projection`` as a ``SolverConfig.trunk_projection`` value (None: not given, keep the default)."""
    choice = getattr(args, "trunk_projection", None)
    return None if choice is None else choice == "on"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``mimic solve``."""
    g = parser.add_argument_group("solver (SolverConfig)")
    add_dataclass_arguments(g, SolverConfig, FLAGS, skip=("damping",))
    parser.add_argument("--no-waist", action="store_true", help="control the 14 arm joints only")
    parser.add_argument("--robot", default=None, help=f"robot profile name or TOML path (default {DEFAULT_PROFILE})")
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
    from services.solver.node import config_from_args, run
    from shared.robot.wheeled import is_wheeled_profile

    try:
        config_from_args(args)
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    if args.robot and is_wheeled_profile(args.robot):
        # A wheeled-legged arm robot (seed 002): its own planner, wbqp-accel, whatever --algo says.
        from services.solver.wbqp_node import run as run_wheeled

        return run_wheeled(args)
    return run(args)
