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
from pathlib import Path

import zenoh

from services.launcher.monitor import BusMonitor
from services.launcher.stack import ROUTER_SERVICE, forget_state, load_stack, local_environment, select
from services.launcher.supervisor import Supervisor
from shared.bus import DEFAULT_ROUTER, wait_for_endpoint
from shared.keys import Keys
from shared.paths import REPO_ROOT

log = logging.getLogger("mimic.up")
STOP_LAST = ("logger", ROUTER_SERVICE)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--demo", action="store_true", help="play the bundled demo motions, stop by itself, print a summary")
    p.add_argument("--session", default=None, help="session name (default $MIMIC_SESSION, 'demo' with --demo)")
    p.add_argument("--endpoint", default=DEFAULT_ROUTER, help="loopback endpoint of the local router")
    p.add_argument(
        "--profile", action="append", default=[], help="also run the compose profile's services (shadow, live)"
    )
    p.add_argument("--only", action="append", default=None, help="run only these services (plus the router)")
    p.add_argument("--restart", action="store_true", help="restart crashed services with exponential backoff")
    p.add_argument("--clips", nargs="*", default=None, help="with --demo: play these clips instead of the bundled ones")
    p.add_argument("--rate", type=float, default=1.0, help="with --demo: playback speed factor")
    p.add_argument("--summary", default=None, help="summary JSON path (default runs/<session>_summary.json)")
    p.add_argument("--ready-timeout", type=float, default=90.0, help="seconds to wait for every service to come up")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (without --demo)")
    p.add_argument("--compose", default=None, help="compose file to read (default: the repo's docker-compose.yml)")


def _mimic_argv(command: list[str]) -> list[str]:
    """Run ``mimic ...`` with this interpreter, so the launcher works from any venv."""
    if command and command[0] == "mimic":
        return [sys.executable, "-m", "services.cli", *command[1:]]
    return command


def _monitor_session(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    return zenoh.open(conf)


def _expected_alive(names: list[str]) -> set[str]:
    # Compose names map to the ServiceRunner names the processes announce.
    alias = {"solver-shadow": "solver"}
    return {alias.get(n, n) for n in names if n != ROUTER_SERVICE}


def _demo_clips(repo: Path, run_dir: Path, sup: Supervisor, env: dict[str, str]) -> list[Path]:
    out = run_dir / "demo_motion"
    child = sup.start("motion", _mimic_argv(["mimic", "demo-motion", str(out)]), env)
    while sup.alive("motion"):
        time.sleep(0.1)
    sup.poll()
    code = child.exit_codes[-1] if child.exit_codes else None
    if code != 0:
        raise RuntimeError(f"demo motion generation failed (exit {code})")
    clips = sorted(out.glob("*.bvh"))
    if not clips:
        raise RuntimeError(f"no demo clips were written to {out}")
    return clips


def main(args: argparse.Namespace) -> int:
    repo = REPO_ROOT
    session = args.session or ("demo" if args.demo else os.environ.get("MIMIC_SESSION", "default"))
    env = dict(os.environ, MIMIC_SESSION=session)
    compose = Path(args.compose) if args.compose else None
    stack = load_stack(compose, env) if compose else load_stack(env=env)
    specs = select(stack, args.profile, args.only)
    run_dir = repo / "runs"
    run_dir.mkdir(exist_ok=True)
    keys = Keys(session)

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())

    sup = Supervisor(cwd=str(repo))
    base_env = {"MIMIC_SESSION": session, "MIMIC_CONNECT": args.endpoint}
    monitor = session_z = None
    code = 0
    try:
        for path in forget_state(specs, repo):
            log.info("new stack: removed the previous service state %s", path)
        for spec in specs:
            sup.start(
                spec.name, _mimic_argv(spec.command), local_environment(spec, args.endpoint), restart=args.restart
            )
            if spec.name == ROUTER_SERVICE and not wait_for_endpoint(args.endpoint, 15.0):
                raise RuntimeError(f"router did not open {args.endpoint}")
        session_z = _monitor_session(args.endpoint)
        monitor = BusMonitor(session_z, keys, *_joint_limits())
        expected = _expected_alive([s.name for s in specs])
        deadline = time.monotonic() + args.ready_timeout
        while not expected <= monitor.alive_services():
            crashed = [n for n in sup.poll() if not args.restart]
            if crashed:
                raise RuntimeError(f"services exited during start-up: {crashed} (see their log lines above)")
            if stop.is_set() or time.monotonic() > deadline:
                missing = sorted(expected - monitor.alive_services())
                raise RuntimeError(f"services not up after {args.ready_timeout:.0f} s: {missing}")
            time.sleep(0.1)
        log.info("stack up on session %r: %s", session, ", ".join(s.name for s in specs))

        if args.demo:
            clips = [Path(c) for c in args.clips] if args.clips else _demo_clips(repo, run_dir, sup, base_env)
            for clip in clips:
                if stop.is_set():
                    break
                name = f"play:{clip.stem}"[:24]
                argv = ["mimic", "publish", str(clip), "--rate", str(args.rate), "--wait-subscriber", "10"]
                sup.start(name, _mimic_argv(argv), base_env)
                while sup.alive(name) and not stop.is_set():
                    sup.poll()
                    time.sleep(0.05)
                sup.poll()
            time.sleep(1.5)  # let the last frames drain through solver, sim and logger
        else:
            t_end = time.monotonic() + args.duration if args.duration else None
            while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
                sup.poll()
                time.sleep(0.1)
    except RuntimeError as exc:
        log.error("%s", exc)
        code = 1
    finally:
        order = [n for n in reversed(list(sup.children)) if n not in STOP_LAST]
        order += [n for n in STOP_LAST if n in sup.children]
        codes = sup.stop_all(order)
        forget_state(specs, repo)  # the stack's state lives as long as the stack
        summary = monitor.summary() if monitor else {}
        if monitor:
            monitor.close()
        if session_z is not None:
            session_z.close()
        summary["exit_codes"] = codes
        summary["session"] = session
        rrd = run_dir / f"{session}.rrd"
        summary["recording"] = str(rrd) if rrd.exists() else None
        path = Path(args.summary) if args.summary else run_dir / f"{session}_summary.json"
        path.write_text(json.dumps(summary, indent=2))
        if args.demo or args.summary:
            _print_summary(summary, path)
    return code


def _joint_limits():
    try:
        from shared.robot.pinocchio_model import build_robot_model

        rm = build_robot_model()
        margin = rm.profile.limit_margin  # the URDF limits, not the solver's shrunk ones
        return rm.lower - margin, rm.upper + margin
    except Exception as exc:  # the summary still works without limit checks
        log.warning("joint limits unavailable for the summary: %s", exc)
        return None, None


def _print_summary(s: dict, path: Path) -> None:
    width = shutil.get_terminal_size((100, 20)).columns
    lines = ["", "=" * min(width, 78), "mimic run summary", "=" * min(width, 78)]
    lines.append(f"frames published: {s.get('frames_published')}   robot states: {s.get('robot_states')}")
    lines.append(f"{'service':<22}{'in':>8}{'out':>8}{'dropped':>9}{'rejected':>10}  state")
    for name, c in s.get("services", {}).items():
        lines.append(f"{name:<22}{c['in']:>8}{c['out']:>8}{c['dropped']:>9}{c['rejected']:>10}  {c['state']}")
    lat = s.get("latency_ms", {})

    def f(v, unit=""):
        return "n/a" if v is None else f"{v:.2f}{unit}"

    lines.append(
        f"latency mocap->sim: p50 {f(lat.get('p50'), ' ms')}, p99 {f(lat.get('p99'), ' ms')}"
        f" ({lat.get('samples')} frames)"
    )
    we, ee = s.get("wrist_err_cm", {}), s.get("elbow_err_cm", {})
    lines.append(f"wrist error: mean {f(we.get('mean'), ' cm')}, max {f(we.get('max'), ' cm')}")
    lines.append(f"elbow error: mean {f(ee.get('mean'), ' cm')}, max {f(ee.get('max'), ' cm')}")
    lines.append(
        f"joint limit excess (URDF): commanded {s.get('max_command_limit_excess_rad', 0.0):.2e} rad,"
        f" simulated {s.get('max_joint_limit_excess_rad', 0.0):.2e} rad"
    )
    lines.append(f"recording: {s.get('recording')}")
    lines.append(f"summary: {path}")
    # The summary is the command's product for the user, so it goes to stdout, not the log.
    sys.stdout.write("\n".join(lines) + "\n")
