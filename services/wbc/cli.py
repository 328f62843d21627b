"""``mimic wbc-eval``: seed 002 section 5 (hand along x to x = 2.0 m, z = 0.8 m) in MuJoCo, JSON + Fig. 2(b).

Prints and writes ``{"ee_err_mm": {"mean", "max", "steady_max"}, "torso_vel_err_mps": {"max"},
"torso_att_rad": {"max"}, "solve_ms": {"mean", "p50", "p99"}, "violations": int}`` plus an
``info`` block (planner statuses, per-axis steady errors, settings), and the four curves of the
seed's Fig. 2(b) as PNGs: hand x and z (desired vs actual), torso x velocity (planned vs
actual), torso attitude (pitch, roll).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from shared.config import add_dataclass_arguments, config_from_args
from shared.report import emit_json

log = logging.getLogger("mimic.wbc")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``mimic wbc-eval`` (the reach's from :class:`~services.wbc.runner.WbcEvalConfig`)."""
    from services.wbc.runner import WbcEvalConfig

    parser.add_argument("--robot", default="models/tita_piper.toml", help="wheeled-arm robot profile (TOML)")
    parser.add_argument("--json", default=None, help="write the metrics JSON here (also printed)")
    parser.add_argument("--plots", default=None, help="directory for the Fig. 2(b) PNGs")
    parser.add_argument("--qp", choices=("daqp", "piqp"), default=WbcEvalConfig().planner.qp, help="QP backend")
    add_dataclass_arguments(parser.add_argument_group("reach (WbcEvalConfig)"), WbcEvalConfig, skip=SKIP)


#: WbcEvalConfig fields without flags (component settings, set in code).
SKIP = ("planner", "balance")


def plot(trace: dict, out_dir: Path) -> list[Path]:
    """The four panels of seed 002 Fig. 2(b), one PNG each; returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    t = trace["t"]
    panels = [
        (
            "fig2b_1_hand_x.png",
            "hand x [m]",
            [(trace["p_des"][:, 0], "desired", "g-"), (trace["p_sim"][:, 0], "actual", "r--")],
        ),
        (
            "fig2b_2_hand_z.png",
            "hand z [m]",
            [(trace["p_des"][:, 2], "desired", "g-"), (trace["p_sim"][:, 2], "actual", "r--")],
        ),
        (
            "fig2b_3_torso_vx.png",
            "torso x velocity [m/s]",
            [(trace["vx_plan"], "planned", "g-"), (trace["vx_sim"], "actual", "r--")],
        ),
        (
            "fig2b_4_torso_attitude.png",
            "torso attitude [rad]",
            [(trace["pitch"], "pitch", "b-"), (trace["roll"], "roll", "m--")],
        ),
    ]
    paths = []
    for name, ylabel, series in panels:
        fig, ax = plt.subplots(figsize=(6, 3.2))
        for y, label, style in series:
            ax.plot(t, y, style, label=label, linewidth=1.2)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best")
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def main(args: argparse.Namespace) -> int:
    """Run the reach and report."""
    from services.wbc.runner import WbcEvalConfig, run_reach
    from shared.robot.profile import ProfileError
    from shared.robot.wheeled import build_wheeled_robot

    try:
        robot = build_wheeled_robot(args.robot)
    except (ProfileError, OSError, KeyError) as exc:
        log.error("cannot load robot %s: %s", args.robot, exc)
        return 2
    try:
        cfg = config_from_args(WbcEvalConfig, args)
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    cfg.planner.qp = args.qp
    out = run_reach(cfg, robot)
    report = {**out["metrics"], "info": out["info"]}
    emit_json(report, args.json)
    if args.plots:
        for p in plot(out["trace"], Path(args.plots)):
            log.info("wrote %s", p)
    return 0
