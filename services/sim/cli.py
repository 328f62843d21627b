"""``mimic sim``: MuJoCo simulation following one solver's JointCommands."""

from __future__ import annotations

import argparse
import logging
import os

# MuJoCo reads MUJOCO_GL when first imported; EGL renders without a display.
os.environ.setdefault("MUJOCO_GL", "egl")
# Software GL (llvmpipe) would otherwise take every core away from the physics loop.
os.environ.setdefault("LP_NUM_THREADS", "1")

from shared.bus import add_bus_args
from shared.robot.profile import DEFAULT_PROFILE

log = logging.getLogger("mimic.sim")


def add_sim_options(p: argparse.ArgumentParser) -> None:
    """Robot and servo options shared by ``sim`` and ``sim-track``."""
    g = p.add_argument_group("simulation")
    g.add_argument("--robot", default=DEFAULT_PROFILE, help="robot profile name or TOML path")
    g.add_argument("--timestep", type=float, default=0.001, help="physics step [s] (default 1 kHz)")
    g.add_argument("--no-velocity-ff", action="store_true", help="servos brake against qdot instead of tracking qd")
    g.add_argument("--no-gravity-comp", action="store_true", help="motors do not cancel gravity")
    g.add_argument("--no-contacts", action="store_true", help="disable contacts (self-collisions)")
    g.add_argument(
        "--contact-exclude-hops", type=int, default=3, help="no contacts between a link and this many ancestors"
    )
    g.add_argument("--max-extrapolation", type=float, default=0.05, help="first-order hold past a command [s]")


def sim_config(args: argparse.Namespace, **extra):
    """SimConfig from parsed options."""
    from services.sim.sim_core import SimConfig

    return SimConfig(
        timestep=args.timestep,
        velocity_feedforward=not args.no_velocity_ff,
        gravity_compensation=not args.no_gravity_comp,
        contacts=not args.no_contacts,
        contact_exclude_hops=args.contact_exclude_hops,
        max_extrapolation=args.max_extrapolation,
        **extra,
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_sim_options(p)
    g = p.add_argument_group("sim service")
    g.add_argument("--follow", default="main", help="solver id whose commands are applied (queryable sim/follow)")
    g.add_argument(
        "--clock",
        choices=("realtime", "lockstep"),
        default="realtime",
        help="realtime: wall-clock paced; lockstep: each command advances --lockstep-dt, as fast as possible",
    )
    g.add_argument("--lockstep-dt", type=float, default=0.01, help="simulated time per command in lock-step [s]")
    g.add_argument("--state-rate", type=float, default=200.0, help="RobotState rate in real time [Hz]")
    g.add_argument("--watchdog-ms", type=float, default=100.0, help="hold the pose after this long without commands")
    g.add_argument("--render", default=None, metavar="DIR", help="render offscreen to DIR (sim.mp4 or PNG frames)")
    g.add_argument("--render-fps", type=float, default=10.0, help="rendered frames per simulated second")
    g.add_argument("--render-format", choices=("auto", "mp4", "png"), default="auto", help="mp4 needs ffmpeg")
    add_bus_args(p)


def main(args: argparse.Namespace) -> int:
    from services.sim.node import run
    from services.sim.sim_core import SimCore
    from shared.keys import Keys
    from shared.robot.profile import ProfileError

    try:
        Keys().command(args.follow)
        if args.timestep <= 0 or args.state_rate <= 0 or args.lockstep_dt <= 0 or args.watchdog_ms <= 0:
            raise ValueError("--timestep, --state-rate, --lockstep-dt and --watchdog-ms must be positive")
        config = sim_config(args, watchdog=args.watchdog_ms / 1000.0, solver_id=args.follow)
        core = SimCore(args.robot, config)
    except (ProfileError, ValueError, KeyError) as exc:
        log.error("%s", exc)
        return 2
    return run(args, core)
