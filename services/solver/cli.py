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


#: ``SolverConfig`` switches that the commands building their own solver (``mimic eval``, ``mimic bench solvers``)
#: take as ``--name on|off``, so an on/off comparison runs in one tree: field -> what it switches.
SWITCHES = {
    "self_collision": "the solver's self-collision damper rows",
    "trunk_projection": "move wrist targets inside the waist-carried trunk onto its surface, where the waist holds "
    "it now",
}


def add_switches(parser: argparse.ArgumentParser, switches: dict[str, str] = SWITCHES) -> None:
    """One ``--field on|off`` flag per ``SolverConfig`` field of ``switches`` (field -> help text), default None (keep
    ``SolverConfig``'s); read them back with :func:`switch_values`."""
    for field, text in switches.items():
        parser.add_argument(
            "--" + field.replace("_", "-"),
            choices=("on", "off"),
            default=None,
            help=f"{text} (SolverConfig.{field}; default: SolverConfig's, as shipped)",
        )


def switch_values(args: argparse.Namespace, switches: dict[str, str] = SWITCHES) -> dict[str, bool]:
    """The ``SolverConfig`` values of the switches given on the command line (absent ones are left out)."""
    return {f: getattr(args, f) == "on" for f in switches if getattr(args, f, None) is not None}


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
