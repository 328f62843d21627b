"""``mimic retarget``: HumanFrames -> wrist/elbow TaskTargets on the bus (seed 000 eqs. 1-4).

The retargeting flags are built from :class:`~services.retarget.retargeter.RetargetConfig`
(defaults, units, validation). The mapping mode flag is ``--mapping`` because ``--mode``
is the Zenoh mode shared by every service (:func:`shared.bus.add_bus_args`).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from services.retarget.mapping import ELBOW_PLACEMENTS, MODES, ORIENTATION_REFERENCES
from services.retarget.workspace import Shrink
from shared import config as shared_config
from shared.bus import add_bus_args
from shared.config import add_dataclass_arguments

log = logging.getLogger("mimic.retarget")


def _shrink_arg(text: str) -> Shrink:
    try:
        return Shrink.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: Flag names that differ from the RetargetConfig field names, choices and parsers.
FLAGS = {
    # --mode is the Zenoh mode shared by every service.
    "mode": {"flag": "--mapping", "dest": "mapping", "choices": MODES},
    "samples": {"help": "Monte Carlo workspace samples (paper: 12 000)"},
    "seed": {"help": "workspace sampling seed"},
    "shrink": {
        "type": _shrink_arg,
        "shown_default": "0.05",
        "help": "workspace restriction: '0.05' = 5-95% percentile box, '0.03m' = raw box minus 3 cm, "
        "'0.05,0.01m' = both",
    },
    "elbow_placement": {
        "choices": ELBOW_PLACEMENTS,
        "help": "swivel: elbow targets at the robot's arm lengths, reachable together with the wrist; "
        "mapped: the paper's eqs. 1-3 per axis",
    },
    "orientation_reference": {
        "choices": ORIENTATION_REFERENCES,
        "help": "eq. 4's robot reference: forearm (hand relative to forearm; needs swivel), posture "
        "(robot posture at the calibration targets) or rest (the profile rest pose, the paper read literally)",
    },
    "auto_calibrate": {
        "help": "without --calibration, wait for one on the calibration queryable instead of using the first frame"
    },
}


def add_retarget_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``retarget`` and ``retarget-plot``: the RetargetConfig fields and ``--calibration``."""
    from .retargeter import RetargetConfig

    g = p.add_argument_group("retargeting (RetargetConfig)")
    add_dataclass_arguments(g, RetargetConfig, FLAGS)
    g.add_argument("--calibration", type=Path, default=None, help="operator calibration file (JSON or TOML)")


def config_from_args(args: argparse.Namespace):
    """RetargetConfig from parsed options (validated by RetargetConfig)."""
    from services.retarget.retargeter import RetargetConfig

    return shared_config.config_from_args(RetargetConfig, args, FLAGS)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_retarget_options(p)
    p.add_argument(
        "--save-calibration", type=Path, default=None, help="write every new calibration (auto or set) to this JSON"
    )
    p.add_argument(
        "--calibration-state",
        type=Path,
        default=None,
        help="calibration kept across restarts: loaded at start when it exists (unless --calibration), "
        "rewritten on every new calibration, so a restarted retarget does not recalibrate on a moving operator",
    )
    add_bus_args(p)


def initial_calibration(args: argparse.Namespace):
    """The calibration to start with: ``--calibration``, else ``--calibration-state`` when it
    exists (a restart), else None (auto-calibration on the first rest frame).

    Raises CalibrationError for a bad ``--calibration``; a bad state file is logged and ignored
    so it cannot keep the service down.
    """
    from services.retarget.calibration import Calibration, CalibrationError

    if args.calibration:
        return Calibration.load(args.calibration)
    state = getattr(args, "calibration_state", None)
    if state is None or not state.exists():
        return None
    try:
        calibration = Calibration.load(state)
    except (CalibrationError, ValueError, OSError) as exc:
        log.warning("ignoring calibration state %s: %s; calibrating afresh", state, exc)
        return None
    log.info("calibration restored from %s (%s)", state, calibration.source)
    return calibration


def main(args: argparse.Namespace) -> int:
    from services.retarget.calibration import CalibrationError
    from services.retarget.node import run
    from services.retarget.retargeter import Retargeter
    from shared.robot.wheeled import is_wheeled_profile

    try:
        config = config_from_args(args)
        if is_wheeled_profile(config.robot):
            # A mobile robot: its profile's [retarget] table says what drives what (services/retarget/mobile.py).
            from services.retarget.mobile import MobileRetargeter

            retargeter = MobileRetargeter(config, initial_calibration(args))
        else:
            retargeter = Retargeter(config, initial_calibration(args))
    except (CalibrationError, ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2
    saves = [p for p in (args.save_calibration, getattr(args, "calibration_state", None)) if p is not None]
    return run(args, retargeter, saves)
