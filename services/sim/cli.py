"""``mimic sim``: MuJoCo simulation following one solver's JointCommands."""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

# Software GL (llvmpipe) would otherwise take every core away from the physics loop.
os.environ.setdefault("LP_NUM_THREADS", "1")

from shared.bus import add_bus_args
from shared.config import add_dataclass_arguments, config_from_args
from shared.robot.profile import DEFAULT_PROFILE

log = logging.getLogger("mimic.sim")


def add_sim_options(p: argparse.ArgumentParser) -> None:
    """Robot and servo options shared by ``sim`` and ``sim-track``."""
    from .sim_core import SimConfig

    g = p.add_argument_group("simulation")
    g.add_argument("--robot", default=DEFAULT_PROFILE, help="robot profile name or TOML path")
    add_dataclass_arguments(
        g,
        SimConfig,
        {"velocity_feedforward": {"flag": "--no-velocity-ff"}, "gravity_compensation": {"flag": "--no-gravity-comp"}},
        skip=SERVICE_FIELDS,
    )


#: SimConfig fields that only the sim service has flags for (sim-track runs without a bus).
SERVICE_FIELDS = ("watchdog", "solver_id")


def sim_config(args: argparse.Namespace, **extra):
    """SimConfig from parsed options (validated by SimConfig)."""
    from services.sim.sim_core import SimConfig

    return config_from_args(SimConfig, args, **extra)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_sim_options(p)
    from .sim_core import SimConfig

    g = p.add_argument_group("sim service")
    add_dataclass_arguments(
        g,
        SimConfig,
        {"solver_id": {"flag": "--follow", "help": "solver id whose commands are applied (queryable sim/follow)"}},
        only=SERVICE_FIELDS,
    )
    g.add_argument(
        "--clock",
        choices=("realtime", "lockstep"),
        default="realtime",
        help="realtime: wall-clock paced; lockstep: each command advances --lockstep-dt, as fast as possible",
    )
    g.add_argument("--lockstep-dt", type=float, default=0.01, help="simulated time per command in lock-step [s]")
    g.add_argument("--state-rate", type=float, default=200.0, help="RobotState rate in real time [Hz]")
    g.add_argument(
        "--state-file",
        default="auto",
        help="joint positions kept for a restart: loaded at start when present, rewritten while running "
        "('auto': runs/<session>_sim_state.json; 'none': off)",
    )
    g.add_argument(
        "--state-on-command",
        action="store_true",
        help="realtime: also publish RobotState right after each applied command (latency benches)",
    )
    g.add_argument("--render", default=None, metavar="DIR", help="render offscreen to DIR (sim.mp4 or PNG frames)")
    g.add_argument("--render-fps", type=float, default=10.0, help="rendered frames per simulated second")
    g.add_argument("--render-format", choices=("auto", "mp4", "png"), default="auto", help="mp4 needs ffmpeg")
    add_bus_args(p)


def main(args: argparse.Namespace) -> int:
    # MuJoCo picks its GL backend from MUJOCO_GL when first imported (below). EGL renders without a
    # display; without --render no GL at all, so no OpenGL library is loaded (or missed) in vain.
    os.environ.setdefault("MUJOCO_GL", "egl" if args.render else "disable")
    from services.sim.node import run
    from services.sim.resume import load_state, session_state_file
    from services.sim.sim_core import SimCore
    from shared.keys import Keys
    from shared.robot.profile import ProfileError
    from shared.robot.wheeled import is_wheeled_profile

    try:
        Keys().command(args.solver_id)
        if args.state_rate <= 0 or args.lockstep_dt <= 0:
            raise ValueError("--state-rate and --lockstep-dt must be positive")
        config = sim_config(args)
        if is_wheeled_profile(args.robot):
            # A wheeled-legged arm robot (seed 002): its balancing core follows 7-D commands.
            from services.wbc.sim_core import WheeledSimConfig, WheeledSimCore

            core = WheeledSimCore(
                args.robot,
                WheeledSimConfig(config.timestep, config.watchdog, config.max_extrapolation, config.solver_id),
            )
        else:
            core = SimCore(args.robot, config)
        if args.state_file == "auto":
            args.state_file = session_state_file(args.session)
        if args.state_file != "none" and hasattr(core, "resume"):
            q = load_state(Path(args.state_file), list(core.joint_names))
            if q is not None:
                core.resume(q)
                log.info("resumed from the last state in %s (not the rest pose)", args.state_file)
    except (ProfileError, ValueError, KeyError) as exc:
        log.error("%s", exc)
        return 2
    return run(args, core)
