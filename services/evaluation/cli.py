"""``mimic eval CLIP... --algos ... --json OUT [--plots DIR]``: the paper's comparison on real motion."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

from tqdm import tqdm

from services.evaluation.metrics import REACHABLE_TOL, reachable_mask, summarise, trace_metrics
from services.evaluation.runner import EVAL_RETARGET, REFERENCE_ALGO, load_and_retarget, run_algorithm
from services.ingest.errors import ClipError
from services.retarget.mapping import ELBOW_PLACEMENTS, ORIENTATION_REFERENCES
from services.solver.algorithms import ALGORITHMS
from services.solver.core import SolverConfig
from shared.robot.pinocchio_model import build_robot_model

log = logging.getLogger("mimic.eval")
PAPER = {
    "hqp-nullspace": {"wrist_err_cm": {"mean": 0.12, "max": 0.65}, "elbow_err_cm": {"mean": 0.75, "max": 2.10}},
    "wqp": {"wrist_err_cm": {"mean": 0.22, "max": 2.50}, "elbow_err_cm": {"mean": 5.58, "max": 9.53}},
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("clips", nargs="+", help="BVH or C3D clips")
    p.add_argument("--algos", default="hqp-nullspace,hqp-original,wqp", help=f"comma list of {sorted(ALGORITHMS)}")
    p.add_argument("--qp", default="daqp", choices=("piqp", "daqp"), help="QP backend")
    p.add_argument("--rate", type=float, default=500.0, help="control rate [Hz]")
    p.add_argument("--mapping", default="bounded", choices=("bounded", "paper", "incremental"))
    p.add_argument("--no-sim", action="store_true", help="skip the MuJoCo lock-step run (no *_sim errors)")
    p.add_argument("--no-waist", action="store_true", help="solve the 14 arm joints only")
    p.add_argument(
        "--wrist-orientation-level",
        type=int,
        default=None,
        choices=(1, 2, 3),
        help="1: the paper's hierarchy (wrist poses > elbows > posture); 2: wrist positions > elbows + "
        "wrist orientations > posture; 3: wrist positions > elbows > wrist orientations (default: SolverConfig's)",
    )
    p.add_argument(
        "--elbow-placement",
        default=ELBOW_PLACEMENTS[0],
        choices=ELBOW_PLACEMENTS,
        help="swivel: elbow targets reachable with the wrist target; mapped: the paper's eqs. 1-3 per axis",
    )
    p.add_argument(
        "--velocity-tau",
        type=float,
        default=EVAL_RETARGET["velocity_tau"],
        help="retarget velocity low-pass time constant [s] (0 = raw finite differences)",
    )
    p.add_argument(
        "--orientation-reference",
        default=ORIENTATION_REFERENCES[0],
        choices=ORIENTATION_REFERENCES,
        help="eq. 4 orientation mapping: forearm-relative (default), calibration posture, or the profile rest",
    )
    p.add_argument(
        "--wqp-weights",
        default=None,
        help="wqp level weights, comma list (default 1,0.3,1); 1,0.01,1 is a wrist-only 'traditional QP'",
    )
    p.add_argument(
        "--paper",
        action="store_true",
        help="the paper's setup: orientation level 1, mapped elbows, eq. 4 against the rest pose",
    )
    p.add_argument("--json", required=True, help="output JSON path")
    p.add_argument("--plots", default=None, help="folder for Fig. 9-style PNGs and report.md")


def evaluate(args: argparse.Namespace) -> tuple[dict, dict]:
    """Run every clip and algorithm; returns (result JSON, traces for plotting)."""
    algos, solver, wqp_weights, retarget = _settings(args)
    robot = build_robot_model(with_waist=not args.no_waist)
    # The reachable-tick mask comes from the strict hierarchy, so run it first.
    order = [REFERENCE_ALGO] + [a for a in algos if a != REFERENCE_ALGO]
    clips_out, traces = [], {}
    bar = tqdm(total=len(args.clips) * len(order), desc="eval", unit="run", file=sys.stderr)
    skipped = []
    for path in args.clips:
        try:
            clip, targets = load_and_retarget(Path(path), robot, args.mapping, retarget)
        except (ClipError, OSError, ValueError, RuntimeError) as exc:
            # One bad or unknown-rig clip must not cost the user the whole run: say it in one
            # line, record it, go on with the others.
            log.error("skipping %s: %s", path, exc)
            skipped.append({"clip": str(path), "error": str(exc)})
            bar.update(len(order))
            continue
        entry = {"clip": clip.name, "frames": len(targets), "algos": {}}
        mask = None
        for algo in order:
            bar.set_postfix_str(f"{clip.name[:28]} {algo}")
            tr = run_algorithm(
                robot,
                targets,
                algo,
                qp=args.qp,
                rate=args.rate,
                sim=not args.no_sim,
                solver=solver,
                wqp_weights=wqp_weights,
            )
            if algo == REFERENCE_ALGO:
                mask = reachable_mask(tr)
            if algo in algos:
                entry["algos"][algo] = trace_metrics(tr, robot, mask)
                traces[(clip.name, algo)] = tr
            bar.update(1)
        clips_out.append(entry)
    bar.close()
    if not clips_out:
        raise SystemExit(f"mimic eval: no clip could be evaluated ({len(skipped)} skipped, see above)")
    result = {"clips": clips_out, "skipped": skipped, "summary": summarise(clips_out), "paper": PAPER}
    result["settings"] = _settings_json(args, algos, solver, wqp_weights, retarget, robot.nq)
    return result, traces


def _settings(args: argparse.Namespace) -> tuple[list[str], dict, tuple[float, ...] | None, dict]:
    """(algorithms, SolverConfig fields, wqp weights or None, RetargetConfig fields) from the flags;
    ``--paper`` sets orientation level 1, mapped elbows and eq. 4 against the rest pose."""
    algos = [a.strip() for a in args.algos.split(",") if a.strip()]
    unknown = [a for a in algos if a not in ALGORITHMS]
    if unknown:
        raise SystemExit(f"unknown algorithms {unknown}; known: {sorted(ALGORITHMS)}")
    level = getattr(args, "wrist_orientation_level", None)
    elbows = getattr(args, "elbow_placement", ELBOW_PLACEMENTS[0])
    oref = getattr(args, "orientation_reference", ORIENTATION_REFERENCES[0])
    if getattr(args, "paper", False):
        level, elbows, oref = 1, "mapped", "rest"
    solver = {} if level is None else {"wrist_orientation_level": level}
    wq = getattr(args, "wqp_weights", None)
    wqp_weights = tuple(float(w) for w in wq.split(",")) if wq else None
    retarget = {**EVAL_RETARGET, "elbow_placement": elbows, "orientation_reference": oref}
    retarget["velocity_tau"] = getattr(args, "velocity_tau", EVAL_RETARGET["velocity_tau"])
    return algos, solver, wqp_weights, retarget


def _settings_json(
    args: argparse.Namespace,
    algos: list[str],
    solver: dict,
    wqp_weights: tuple[float, ...] | None,
    retarget: dict,
    dof: int,
) -> dict:
    """What ran, for the result JSON (anyone can rerun it from these)."""
    return {
        "algos": algos,
        "qp": args.qp,
        "rate_hz": args.rate,
        "mapping": args.mapping,
        "retarget": retarget,
        "wqp_weights": list(wqp_weights) if wqp_weights else "default (1.0, 0.3, 1.0)",
        "solver": {
            "wrist_orientation_level": SolverConfig(**solver).wrist_orientation_level,
            "gain": SolverConfig().gain,
            "orientation_gain": SolverConfig().orientation_gain,
            "damping": list(SolverConfig().damping),
        },
        "dof": dof,
        "sim": not args.no_sim,
        "reachable_tol": REACHABLE_TOL,
        "error_reference": "retargeted target, extrapolated with its velocity, at the instant each "
        "tick's command is for (t + dt)",
    }


def main(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    result, traces = evaluate(args)
    result["settings"]["wall_s"] = time.perf_counter() - t0
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    if args.plots:
        from services.evaluation.report import write_report

        write_report(result, traces, Path(args.plots))
    sys.stdout.write(json.dumps(result["summary"], indent=2) + "\n")
    log.info("wrote %s in %.1f s", out, result["settings"]["wall_s"])
    return 0
