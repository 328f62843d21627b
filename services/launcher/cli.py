"""``mimic up``: the whole stack as local processes (what docker-compose runs).

With ``--demo`` it also generates the project's own demo motions, plays them
live, stops by itself and prints a summary (also written as JSON).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import signal
import sys
import threading
import time
import tomllib
from pathlib import Path

from services.launcher.local_stack import LocalStack
from services.launcher.monitor import STARTUP_S, BusMonitor
from services.launcher.session_lock import SessionBusyError, SessionLock
from services.launcher.solver_swap import SolverSwap
from services.launcher.stack import ROUTER_SERVICE, select
from shared.bus import DEFAULT_ROUTER, free_port
from shared.paths import REPO_ROOT, unused_path

log = logging.getLogger("mimic.up")
#: Stopped after the others (the logger records the stack going down).
STOP_LAST = ("logger",)
#: The logger's grace at stop [s]: it compacts the recording before it exits.
LOGGER_STOP_S = 90.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--demo", action="store_true", help="play the bundled demo motions, stop by itself, print a summary")
    p.add_argument("--session", default=None, help="session name (default $MIMIC_SESSION, 'demo' with --demo)")
    p.add_argument("--endpoint", default=DEFAULT_ROUTER, help="loopback endpoint of the local router")
    p.add_argument(
        "--profile", action="append", default=[], help="also run the compose profile's services (shadow, live)"
    )
    p.add_argument(
        "--only",
        action="append",
        default=None,
        help="run only these services (plus the router): repeat it or give a comma list (--only solver,sim)",
    )
    p.add_argument("--restart", action="store_true", help="restart crashed services with exponential backoff")
    p.add_argument("--clips", nargs="*", default=None, help="with --demo: play these clips instead of the bundled ones")
    p.add_argument("--rate", type=float, default=1.0, help="with --demo: playback speed factor")
    p.add_argument(
        "--summary",
        default=None,
        help="summary JSON path (default runs/<recording name>_summary.json); an existing file is kept and the "
        "summary goes to the first free <name>-<n>.json, unless --overwrite",
    )
    p.add_argument(
        "--overwrite", action="store_true", help="replace an existing recording and summary instead of numbering"
    )
    p.add_argument("--ready-timeout", type=float, default=90.0, help="seconds to wait for every service to come up")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (without --demo)")
    p.add_argument(
        "--beside",
        action="store_true",
        help="run beside a stack already up: a free loopback port and the first free session <session>-<n>",
    )
    p.add_argument("--compose", default=None, help="compose file to read (default: the repo's docker-compose.yml)")
    p.add_argument(
        "--robot",
        default=None,
        help="robot profile name or TOML file for every service (default $MIMIC_ROBOT, else the G1)",
    )


def _demo_clips(run_dir: Path, stack: LocalStack) -> list[Path]:
    out = run_dir / "demo_motion"
    stack.start("motion", argv=["mimic", "demo-motion", str(out)], service=False)
    while stack.running("motion"):
        time.sleep(0.1)
    stack.sup.poll()
    child = stack.sup.children["motion"]
    code = child.exit_codes[-1] if child.exit_codes else None
    if code != 0:
        raise RuntimeError(f"demo motion generation failed (exit {code})")
    clips = sorted(out.glob("*.bvh"))
    if not clips:
        raise RuntimeError(f"no demo clips were written to {out}")
    return clips


def only_services(values: list[str] | None) -> list[str] | None:
    """The ``--only`` service names: repeated flags and comma lists alike (None: every service)."""
    if values is None:
        return None
    return [n.strip() for v in values for n in v.split(",") if n.strip()]


def main(args: argparse.Namespace) -> int:
    session = args.session or ("demo" if args.demo else os.environ.get("MIMIC_SESSION", "default"))
    run_dir = REPO_ROOT / "runs"
    run_dir.mkdir(exist_ok=True)

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())

    try:
        robot = check_robot(args.robot or os.environ.get("MIMIC_ROBOT") or None)
    except ValueError as exc:
        log.error("%s", exc)
        return 1
    endpoint = args.endpoint
    if args.beside:
        endpoint, session = f"tcp/127.0.0.1:{free_port()}", _free_session(run_dir, session)
    try:
        stack = LocalStack(
            session,
            endpoint,
            out=sys.stdout,
            restart=args.restart,
            compose=Path(args.compose) if args.compose else None,
            env={"MIMIC_ROBOT": robot} if robot else None,
        )
    except (SessionBusyError, ValueError, OSError) as exc:
        log.error("%s", exc)
        return 1
    try:
        specs = select(stack.spec, args.profile, only_services(args.only))
    except ValueError as exc:
        stack.close()
        log.error("%s", exc)
        return 1
    names = [s.name for s in specs if s.name != ROUTER_SERVICE]
    # Never overwrite an earlier recording of the session: the next free runs/<session>[-n].rrd.
    rrd = run_dir / f"{session}.rrd"
    rrd = rrd if args.overwrite else unused_path(rrd)
    extra = {"logger": ["--rrd", str(rrd), *(["--overwrite"] if args.overwrite else [])]}
    monitor = swap = None
    code = 0
    try:
        stack.start_router()
        monitor = BusMonitor(stack.bus, stack.keys, *_joint_limits(robot))
        stack.start_all(names, extra=extra, timeout=args.ready_timeout, stop=stop)
        swap = SolverSwap(stack)  # mimic swap-solver
        log.info(
            "stack up on session %r, router %s: %s (recording %s)",
            session,
            endpoint,
            ", ".join(s.name for s in specs),
            rrd if "logger" in names else "none",
        )

        if args.demo:
            clips = [Path(c) for c in args.clips] if args.clips else _demo_clips(run_dir, stack)
            for clip in clips:
                if stop.is_set():
                    break
                name = f"play:{clip.stem}"[:24]
                stack.start(
                    name,
                    # One status per clip (publish/<clip>), not the last clip's counts as the run's.
                    argv=[
                        "mimic",
                        "publish",
                        str(clip),
                        "--rate",
                        str(args.rate),
                        "--wait-subscriber",
                        "10",
                        "--instance",
                        _instance(clip.stem),
                    ],
                    service=False,
                )
                while stack.running(name) and not stop.is_set():
                    stack.sup.poll()
                    swap.poll()
                    time.sleep(0.05)
                stack.sup.poll()
            time.sleep(1.5)  # let the last frames drain through solver, sim and logger
        else:
            t_end = time.monotonic() + args.duration if args.duration else None
            while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
                stack.sup.poll()
                swap.poll()
                time.sleep(0.1)
    except RuntimeError as exc:
        log.error("%s", exc)
        code = 1
    finally:
        if swap:
            swap.close()
        codes = stack.stop(last=STOP_LAST, timeouts={"logger": LOGGER_STOP_S})
        summary = monitor.summary() if monitor else {}  # with the services' last status, sent while stopping
        if monitor:
            monitor.close()
        stack.close()
        summary["exit_codes"] = codes
        summary["session"] = session
        summary["recording"] = str(rrd) if rrd.exists() else None
        path = summary_path(args, rrd)
        path.write_text(json.dumps(summary, indent=2))
        log.info("summary written: %s", path)
        if args.demo or args.summary:
            _print_summary(summary, path)
    return code


def summary_path(args: argparse.Namespace, rrd: Path) -> Path:
    """Where this run's summary goes: ``--summary`` or ``<recording stem>_summary.json`` beside the
    recording (so ``demo-1.rrd`` pairs with ``demo-1_summary.json``), never over an earlier file
    unless ``--overwrite`` (the recordings' rule, :func:`shared.paths.unused_path`)."""
    path = Path(args.summary) if args.summary else rrd.with_name(f"{rrd.stem}_summary.json")
    return path if args.overwrite else unused_path(path)


def _free_session(run_dir: Path, session: str) -> str:
    """First ``<session>-<n>`` (n = 2, 3, ...) that no live stack holds."""
    n = 2
    while SessionLock(run_dir, f"{session}-{n}").owner() is not None:
        n += 1
    return f"{session}-{n}"


def check_robot(robot: str | None) -> str | None:
    """The robot profile the services get, checked now (a bad one is one line here, not four crashed
    services): None = their default; a file becomes an absolute path (the services run from the repo).

    Raises:
        ValueError (ProfileError): unknown or malformed profile, with the reason.
    """
    if robot is None:
        return None
    from shared.robot.profile import load_profile
    from shared.robot.wheeled import is_wheeled_profile, load_wheeled_profile

    if Path(robot).is_file():
        robot = str(Path(robot).resolve())
    try:
        (load_wheeled_profile if is_wheeled_profile(robot) else load_profile)(robot)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"robot profile {robot}: not valid TOML: {exc}") from None
    return robot


def _joint_limits(robot: str | None = None):
    try:
        from shared.robot.wheeled import build_wheeled_robot, is_wheeled_profile, planner_limits

        if robot and is_wheeled_profile(robot):
            return planner_limits(build_wheeled_robot(robot))  # what its commands and states carry
        from shared.robot.pinocchio_model import build_robot_model

        rm = build_robot_model(robot) if robot else build_robot_model()
        margin = rm.profile.limit_margin  # the URDF limits, not the solver's shrunk ones
        return rm.lower - margin, rm.upper + margin
    except Exception as exc:  # the summary still works without limit checks
        log.warning("joint limits unavailable for the summary: %s", exc)
        return None, None


#: What the summary's figures mean (printed under it: a newcomer must not read "dropped" as lost).
LEGEND = (
    "",
    "in/out: messages received/published by each service. dropped: skipped by design, not lost: each stage",
    "  keeps only the newest input (the sim applies the latest of the solver's 500 Hz commands, the solver",
    "  solves on the newest targets, retarget skips frames that went stale behind newer ones). rejected: bad or",
    "  out-of-order input (uncalibrated, another source, ...): worth a look, see last_error in the JSON.",
    "latency: a frame entering the bus -> the first simulated state that applied it (under CPU load it grows).",
    "error: simulated robot vs its targets, last state of each frame. start-up: the first "
    f"{STARTUP_S:g} s of each stream",
    "  (a clip, a restarted source, a source back after a silence), while the robot moves from where it",
    "  stood onto the operator's pose; steady: the tracking itself (JSON: error_split says the rule).",
)


def _instance(stem: str) -> str:
    """A bus instance id (one key chunk) from a clip name."""
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in stem)[:32] or "clip"


def _print_summary(s: dict, path: Path) -> None:
    width = shutil.get_terminal_size((100, 20)).columns
    lines = ["", "=" * min(width, 78), "mimic run summary", "=" * min(width, 78)]
    lines.append(f"frames published: {s.get('frames_published')}   robot states: {s.get('robot_states')}")
    lines.append(f"{'service':<22}{'in':>8}{'out':>8}{'dropped':>9}{'rejected':>10}  state")
    for name, c in s.get("services", {}).items():
        lines.append(f"{name:<22}{c['in']:>8}{c['out']:>8}{c['dropped']:>9}{c['rejected']:>10}  {c['state']}")
        if c.get("outcomes"):
            lines.append(f"{'':<22}outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(c["outcomes"].items())))
    lat = s.get("latency_ms", {})

    def f(v, unit=""):
        return "n/a" if v is None else f"{v:.2f}{unit}"

    lines.append(
        f"latency mocap->sim: p50 {f(lat.get('p50'), ' ms')}, p99 {f(lat.get('p99'), ' ms')}"
        f" ({lat.get('samples')} frames)"
    )
    we, ee = s.get("wrist_err_cm", {}), s.get("elbow_err_cm", {})
    startup_s = s.get("error_split", {}).get("startup_s")
    for name, e in (("wrist", we), ("elbow", ee)):
        st, up = e.get("steady", {}), e.get("startup", {})
        lines.append(
            f"{name} error, steady: mean {f(st.get('mean'), ' cm')}, p95 {f(st.get('p95'), ' cm')},"
            f" max {f(st.get('max'), ' cm')}   start-up (first {startup_s} s): max {f(up.get('max'), ' cm')}"
        )
    lines.append(
        f"joint limit excess (URDF): commanded {s.get('max_command_limit_excess_rad', 0.0):.2e} rad,"
        f" simulated {s.get('max_joint_limit_excess_rad', 0.0):.2e} rad"
    )
    lines.append(f"recording: {s.get('recording')}")
    lines.extend(LEGEND)
    lines.append(f"summary: {path}")
    # The summary is the command's product for the user, so it goes to stdout, not the log.
    sys.stdout.write("\n".join(lines) + "\n")
