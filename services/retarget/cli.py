"""``mimic retarget``: HumanFrames -> wrist/elbow TaskTargets on the bus (seed 000 eqs. 1-4).

The mapping mode flag is ``--mapping`` because ``--mode`` is the Zenoh mode shared by
every service (:func:`shared.bus.add_bus_args`).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from services.retarget.mapping import ELBOW_PLACEMENTS, MODES, ORIENTATION_REFERENCES
from services.retarget.workspace import DEFAULT_SAMPLES, Shrink
from shared.bus import add_bus_args
from shared.robot.profile import DEFAULT_PROFILE

log = logging.getLogger("mimic.retarget")


def _shrink_arg(text: str) -> Shrink:
    try:
        return Shrink.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_retarget_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``retarget`` and ``retarget-plot``."""
    g = p.add_argument_group("retargeting")
    g.add_argument("--mapping", choices=MODES, default="bounded", help="position mapping mode (default bounded)")
    g.add_argument("--robot", default=DEFAULT_PROFILE, help="robot profile name or TOML path")
    g.add_argument("--calibration", type=Path, default=None, help="operator calibration file (JSON or TOML)")
    g.add_argument("--samples", type=int, default=DEFAULT_SAMPLES, help="Monte Carlo workspace samples")
    g.add_argument("--seed", type=int, default=0, help="workspace sampling seed")
    g.add_argument(
        "--shrink",
        type=_shrink_arg,
        default=Shrink(),
        help="workspace restriction: '0.05' = 5-95%% percentile box (default), '0.03m' = raw box minus 3 cm, "
        "'0.05,0.01m' = both",
    )
    g.add_argument("--with-waist", action="store_true", help="sample the waist joints too for the workspace")
    g.add_argument("--gain", type=float, default=1.0, help="incremental mapping gain k")
    g.add_argument("--velocity-tau", type=float, default=0.05, help="velocity low-pass time constant [s]")
    g.add_argument("--elbow-rotation", action="store_true", help="publish elbow orientations as used (use_rotation)")
    g.add_argument(
        "--elbow-placement",
        choices=ELBOW_PLACEMENTS,
        default=ELBOW_PLACEMENTS[0],
        help="swivel (default): elbow targets at the robot's arm lengths, reachable together with the wrist; "
        "mapped: the paper's eqs. 1-3 per axis",
    )
    g.add_argument(
        "--orientation-reference",
        choices=ORIENTATION_REFERENCES,
        default=ORIENTATION_REFERENCES[0],
        help="eq. 4's robot reference: forearm (default, hand relative to forearm; needs swivel), posture "
        "(robot posture at the calibration targets) or rest (the profile rest pose, the paper read literally)",
    )


def config_from_args(args: argparse.Namespace):
    """RetargetConfig from parsed options."""
    from services.retarget.retargeter import RetargetConfig

    return RetargetConfig(
        mode=args.mapping,
        robot=args.robot,
        samples=args.samples,
        seed=args.seed,
        with_waist=args.with_waist,
        shrink=args.shrink,
        gain=args.gain,
        velocity_tau=args.velocity_tau,
        elbow_rotation=args.elbow_rotation,
        elbow_placement=args.elbow_placement,
        orientation_reference=args.orientation_reference,
        auto_calibrate=not getattr(args, "no_auto_calibrate", False),
    )


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
    p.add_argument(
        "--no-auto-calibrate",
        action="store_true",
        help="without --calibration, wait for one on the calibration queryable instead of using the first frame",
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

    try:
        config = config_from_args(args)
        retargeter = Retargeter(config, initial_calibration(args))
    except (CalibrationError, ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2
    saves = [p for p in (args.save_calibration, getattr(args, "calibration_state", None)) if p is not None]
    return run(args, retargeter, saves)
