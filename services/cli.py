"""The ``mimic`` console script: one subcommand per service or tool.

Subcommand modules are imported lazily so ``mimic --help`` is instant and a
service only loads the libraries it needs. Each module provides
``add_arguments(parser)`` and ``main(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from shared.bus import setup_logging

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "up": ("services.launcher.cli", "run the whole stack as local processes (the embedded default)"),
    "router": ("services.router.cli", "Zenoh router the local services connect to"),
    "publish": ("services.ingest.publish_cli", "play a recorded clip (BVH/C3D) onto the bus in real time"),
    "ingest": ("services.ingest.cli", "live ingest: HumanFrame UDP bridge and Xsens MVN streaming"),
    "demo-motion": ("services.ingest.demo_cli", "generate the embedded demo motions as BVH"),
    "retarget": ("services.retarget.cli", "retarget HumanFrames to wrist/elbow TaskTargets (seed 000 eqs 1-4)"),
    "calibrate": (
        "services.retarget.calibrate_cli",
        "show, redo (--recalibrate) or set (--file) a running retarget's calibration",
    ),
    "source": (
        "services.retarget.source_cli",
        "show or choose the mocap source the running retarget follows (two sources at once)",
    ),
    "retarget-plot": ("services.retarget.plot_cli", "plot operator vs robot workspaces and mapped trajectories"),
    "solve": ("services.solver.cli", "strict-priority HQP solver publishing JointCommands"),
    "sim": ("services.sim.cli", "MuJoCo simulation following one solver's commands"),
    "follow": ("services.sim.follow_cli", "show or switch the solver the running sim follows (local solver swap)"),
    "swap-solver": (
        "services.launcher.swap_cli",
        "replace the running solver of a mimic up stack: start another algorithm, follow it, stop the old one",
    ),
    "log": ("services.logger.cli", "Rerun logger recording everything on the bus"),
    "eval": ("services.evaluation.cli", "offline evaluation of algorithms on clips (JSON + plots)"),
    "posture": ("services.posture.cli", "learned posture policy from wrist-only input: train, bench, gate (seed 004)"),
    "bench": ("services.evaluation.bench_cli", "benchmarks (JSON): solvers, pipeline, logger, recorder, ingest, ..."),
    "wbc-eval": ("services.wbc.cli", "seed 002 section 5: wheeled-legged arm reach in MuJoCo (JSON + Fig. 2(b))"),
    "record": ("services.recorder.record_cli", "record every bus message to MCAP"),
    "replay": ("services.recorder.replay_cli", "replay an MCAP recording onto the bus"),
}


def _load(name: str):
    return importlib.import_module(COMMANDS[name][0])


def build_parser(selected: str | None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mimic", description="Real-time human motion imitation over a Zenoh bus.")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING (also $MIMIC_LOG)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, help_text) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        if name == selected:
            _load(name).add_arguments(sp)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    selected = next((a for a in argv if a in COMMANDS), None)
    parser = build_parser(selected)
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_help()
        return 2
    setup_logging(args.log_level, prefix=f"[{args.command}] ")
    return int(_load(args.command).main(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
