"""``mimic eval CLIP... --algos ... --json OUT [--plots DIR]``: the paper's comparison on real motion."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

from tqdm import tqdm

from services.evaluation.causes import explain_misses
from services.evaluation.goals import clip_goals, goals_lines, goals_summary, load_bars
from services.evaluation.metrics import (
    REACHABLE_TOL,
    compare,
    has_waist,
    operator_errors,
    operator_waist_turn,
    published_waist,
    reachable_mask,
    summarise,
    target_adjustment,
    trace_metrics,
    waist_vs_operator,
)
from services.evaluation.mink_peer import PEERS, MinkMissingError, require_mink
from services.evaluation.reachability import IK_TOL, PAIR_TOL, check_targets
from services.evaluation.runner import REFERENCE_ALGO, SETTLE, _arms_model, load_and_retarget, run_algorithm
from services.ingest.demo_motion import DEMO_MOTIONS, demo_clip_paths
from services.ingest.errors import ClipError
from services.retarget.mapping import ELBOW_PLACEMENTS, MODES, ORIENTATION_REFERENCES
from services.retarget.retargeter import RetargetConfig
from services.solver.cli import SWITCHES, add_switches, switch_values
from services.solver.core import SATURATION_TRIGGERS, SolverConfig
from services.solver.registry import ALGORITHMS
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import load_profile

log = logging.getLogger("mimic.eval")
#: Retarget options that move the published targets away from the plain retargeted ones (flag help):
#: with any of them on, each clip is also retargeted without them and scored against that too.
MOVING_OPTIONS = {
    "consistent_targets": "publish per arm the elbow and wrist orientation of the posture meeting the wrist target",
    "wrist_range": "clip the wrist orientation targets into the wrist joints' ranges",
    "trunk_clearance": "keep the robot hands at the wrist targets off its trunk (waist at rest) by the safety distance",
}
#: Every retarget switch ``mimic eval`` takes as ``--[no-]<field>`` (RetargetConfig field -> flag help).
RETARGET_SWITCHES = {
    **MOVING_OPTIONS,
    "forearm_blend": "fade the forearm alignment of the wrist orientation as an arm straightens instead of switching",
}
#: ``--paper``: the wrist orientation rows' cost on level 1 beside the positions, as before session 18 (the shipped
#: 0.045 is the orientations' weight beside the elbows on level 2, not the paper's full wrist pose).
PAPER_ORIENTATION_COST = 0.3
PAPER = {
    "hqp-nullspace": {"wrist_err_cm": {"mean": 0.12, "max": 0.65}, "elbow_err_cm": {"mean": 0.75, "max": 2.10}},
    "wqp": {"wrist_err_cm": {"mean": 0.22, "max": 2.50}, "elbow_err_cm": {"mean": 5.58, "max": 9.53}},
}


#: The solver's on/off switches ``mimic eval`` takes (``--field on|off``): the shared ones and two of its own.
EVAL_SWITCHES = SWITCHES | {
    "recovery": "strict HQPs: the lock-up recovery",
    "target_acceleration": "extrapolate the targets between frames with the acceleration between consecutive "
    "frames; the tick errors' reference and mink's targets follow the same extrapolation",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("clips", nargs="*", help="BVH or C3D clips")
    p.add_argument(
        "--demo",
        action="append",
        choices=sorted(DEMO_MOTIONS),
        default=[],
        help="also evaluate a bundled demo motion, generated as mimic publish --demo plays it (repeatable)",
    )
    p.add_argument(
        "--algos",
        default="hqp-nullspace,hqp-original,wqp",
        help=f"comma list of {[*sorted(ALGORITHMS), *PEERS]} (mink: the peer, mink.solve_ik on the same targets; "
        "mink-limited: the same, its velocities clipped into our solvers' position/velocity/acceleration box)",
    )
    p.add_argument(
        "--skeleton-map", default=None, help="BVH skeleton map / C3D marker map file (TOML/JSON), as mimic publish"
    )
    p.add_argument(
        "--mirror",
        action="store_true",
        help="held-out motion: evaluate each clip's mirror image (the operator reflected through the sagittal "
        "plane, left and right swapped: a left-handed wave from a right-handed one)",
    )
    p.add_argument(
        "--speed",
        type=_speed_factor,
        default=1.0,
        help="held-out motion: play each clip this many times as fast (e.g. 1.25; the frames are the same)",
    )
    p.add_argument(
        "--settle",
        type=_settle_time,
        default=SETTLE,
        metavar="S",
        help=f"seconds the first frame is held, the robot moving from its rest pose to it, before the clip plays and "
        f"is scored (default {SETTLE}); a run at another settle (0.51) shows how much of a difference between two "
        "runs is the strict HQP's path dependence (evaluation README, eval-diff)",
    )
    p.add_argument("--qp", default="daqp", choices=("piqp", "daqp"), help="QP backend")
    p.add_argument("--rate", type=float, default=500.0, help="control rate [Hz]")
    p.add_argument(
        "--mapping",
        default=RetargetConfig().mode,
        choices=MODES,
        help=f"retarget position mapping (default: the service's, {RetargetConfig().mode})",
    )
    p.add_argument("--no-sim", action="store_true", help="skip the MuJoCo lock-step run (no *_sim errors)")
    p.add_argument("--no-waist", action="store_true", help="solve the 14 arm joints only")
    add_switches(p, EVAL_SWITCHES)
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
        default=RetargetConfig().elbow_placement,
        choices=ELBOW_PLACEMENTS,
        help="swivel: elbow targets reachable with the wrist target; mapped: the paper's eqs. 1-3 per axis",
    )
    p.add_argument(
        "--max-joint-velocity",
        type=_speed_cap,
        default=None,
        metavar="RAD_S",
        help="cap every joint's speed at this [rad/s] instead of the profile's max_joint_velocity (the G1's: 8): "
        "the solvers' box, mink's limits and the sim servo all take it (what a faster robot profile would do)",
    )
    p.add_argument(
        "--velocity-tau",
        type=float,
        default=RetargetConfig().velocity_tau,
        help="retarget velocity low-pass time constant [s] (default: the service's)",
    )
    for field, text in RETARGET_SWITCHES.items():
        moves = (
            "; the JSON then gives, per clip, how far the targets moved from the plain retargeted ones "
            "(target_adjustment) and the errors against those (*_vs_operator)"
            if field in MOVING_OPTIONS
            else ""
        )
        p.add_argument(
            f"--{field.replace('_', '-')}",
            action=argparse.BooleanOptionalAction,
            default=getattr(RetargetConfig(), field),
            help=f"{text} (RetargetConfig.{field}; default: the service's){moves}",
        )
    p.add_argument(
        "--trunk-clearance-fast",
        type=float,
        default=RetargetConfig().trunk_clearance_fast,
        help="with --trunk-clearance: the clearance [m] for a fast hand (RetargetConfig.trunk_clearance_fast; "
        "default: the service's; the full clearance, 0.02 on the G1, keeps it at every speed)",
    )
    p.add_argument(
        "--no-ik-check",
        action="store_true",
        help="skip the IK reachability check of the published targets (no reachable_fraction, stuck_s)",
    )
    p.add_argument(
        "--orientation-reference",
        default=None,
        choices=ORIENTATION_REFERENCES,
        help="eq. 4 orientation mapping: forearm-relative (default; posture with --wrist-only), calibration "
        "posture, or the profile rest",
    )
    p.add_argument(
        "--wqp-weights",
        default=None,
        help="wqp level weights, comma list (default 1,0.3,1); 1,0.01,1 is a wrist-only 'traditional QP'",
    )
    p.add_argument(
        "--paper",
        action="store_true",
        help="the paper's setup: paper mapping (eqs. 1-3), orientation level 1, mapped elbows with their "
        "orientations (the elbow pose) on level 2, eq. 4 against the rest pose, no trunk push, strict on every "
        "tick (no saturation trade)",
    )
    p.add_argument(
        "--wrist-only",
        action="store_true",
        help="the solver sees the wrist targets only (a VR-controller source); runs, per clip, the full-mocap "
        "reference (full:<algo>), wrist-only with the rest-posture level (wrist-only:<algo>) and, with "
        "--posture-policy, wrist-only with the learned posture (wrist-only+policy:<algo>); elbow errors are "
        "against the operator's retargeted elbows. Orientations default to --orientation-reference posture "
        "(forearm reads the elbow)",
    )
    p.add_argument("--posture-policy", default=None, help="learned posture policy file (mimic posture train)")
    p.add_argument(
        "--saturation-weight",
        type=float,
        default=None,
        help="strict HQPs: trade a saturated wrist level against the lower levels at this weight (SolverConfig."
        "saturation_weight; default: SolverConfig's, 4; 0 = strict on every tick, as with --paper)",
    )
    p.add_argument(
        "--waist-follow-cost",
        type=float,
        default=None,
        help="strict HQPs: pull the waist towards the operator's torso on level 2 at this weight [1/rad] "
        "(SolverConfig.waist_follow_cost; default: SolverConfig's, 0 = off); compare waist_vs_operator_deg",
    )
    p.add_argument(
        "--waist-damping-cost",
        type=float,
        default=None,
        help="strict HQPs: damp the waist's velocity towards zero on level 2 at this weight [s/rad] "
        "(SolverConfig.waist_damping_cost; default: SolverConfig's, 0 = off); compare waist_speed_rms and the "
        "*_sim errors",
    )
    p.add_argument(
        "--saturation-trigger",
        choices=SATURATION_TRIGGERS,
        default=None,
        help="with --saturation-weight: trade only ticks whose target velocity is out of the joints' speed reach "
        "(feedforward) or every tick the wrist level misses (residual) (SolverConfig.saturation_trigger; "
        "default: SolverConfig's)",
    )
    p.add_argument(
        "--goals",
        default=None,
        metavar="FILE",
        help="TOML file whose [bars] table sets other bars for the fidelity goals each clip is checked against "
        "(key = number; the keys are in the JSON's summary.goals; default: issue 12's)",
    )
    p.add_argument("--json", required=True, help="output JSON path")
    p.add_argument("--plots", default=None, help="folder for Fig. 9-style PNGs and report.md")


def _positive(expected: str, must_be: str, zero: bool = False):
    """An argparse type: a finite number > 0 (>= 0 with ``zero``), else a one-line usage error naming ``expected`` /
    ``must_be``."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not (math.isfinite(v) and (v > 0 or (zero and v == 0))):
            raise argparse.ArgumentTypeError(f"must be {must_be}, got {text!r}")
        return v

    return parse


#: ``--speed``: a play-back factor; ``--max-joint-velocity``: a speed [rad/s]; ``--settle``: a time [s].
_speed_factor = _positive("a speed factor such as 1.25", "a finite factor > 0")
_speed_cap = _positive("a speed in rad/s", "a finite speed > 0 [rad/s]")
_settle_time = _positive("a time in seconds such as 0.5", "a finite time >= 0 [s]", zero=True)


def evaluate(args: argparse.Namespace) -> tuple[dict, dict]:
    """Run every clip and algorithm; returns (result JSON, traces for plotting)."""
    demos = getattr(args, "demo", [])
    if not args.clips and not demos:
        raise SystemExit("mimic eval: give at least one clip or --demo NAME")
    algos, solver, wqp_weights, retarget = _settings(args)
    try:
        bars = load_bars(args.goals) if getattr(args, "goals", None) else {}
    except ValueError as exc:
        raise SystemExit(f"mimic eval: {exc}") from None
    profile = load_profile()
    if getattr(args, "max_joint_velocity", None) is not None:
        profile = replace(profile, max_joint_velocity=args.max_joint_velocity)
    robot = build_robot_model(profile, with_waist=not args.no_waist)
    ik_check = not getattr(args, "no_ik_check", False)
    sim = not args.no_sim
    # The level-1 tick mask comes from the strict hierarchy, so run it first.
    order = [REFERENCE_ALGO] + [a for a in algos if a != REFERENCE_ALGO]
    wrist_only, policy = getattr(args, "wrist_only", False), getattr(args, "posture_policy", None)
    # (label, algo, wrist-only, solver settings) of every run on a clip
    runs = [(a, a, False, solver) for a in order]
    if wrist_only:
        runs = [(f"full:{REFERENCE_ALGO}", REFERENCE_ALGO, False, solver)]
        runs += [(f"wrist-only:{a}", a, True, solver) for a in algos]
        if policy:
            runs += [(f"wrist-only+policy:{a}", a, True, {**solver, "posture_policy": policy}) for a in algos]
    clips_out, traces = [], {}
    skeleton_map = getattr(args, "skeleton_map", None)
    # held-out variants of every clip (ingest.variants): the same for each clip and algorithm
    variant = {"mirror": getattr(args, "mirror", False), "speed": getattr(args, "speed", 1.0)}
    settle = getattr(args, "settle", SETTLE)
    paths = [*args.clips, *demo_clip_paths(demos)]
    bar = tqdm(total=len(paths) * len(runs), desc="eval", unit="run", file=sys.stderr)
    skipped: list[dict] = []
    failed: list[dict] = []  # (clip, algo) runs that raised: recorded, the rest go on
    for path in paths:
        try:
            clip, targets = load_and_retarget(Path(path), robot, None, retarget, skeleton_map, **variant)
        except (ClipError, OSError, ValueError, RuntimeError) as exc:
            # One bad or unknown-rig clip must not cost the user the whole run: say it in one
            # line, record it, go on with the others.
            log.error("skipping %s: %s", path, exc)
            skipped.append({"clip": str(path), "error": str(exc)})
            bar.update(len(runs))
            continue
        entry = {"clip": clip.name, "frames": len(targets), "algos": {}}
        # the operator's torso as waist angles, as published (seq = frame index); None without a measured chest
        op_waist = published_waist(targets) if has_waist(robot) else None
        if op_waist is not None:  # how far the operator's own torso turned: the scale of waist_vs_operator_deg
            entry["operator_waist_deg"] = operator_waist_turn(op_waist, robot)
        plain = None
        if any(retarget.get(k) for k in MOVING_OPTIONS):
            # what the operator's motion gave before the targets were moved towards what the arm can do
            unmoved = {**retarget, **dict.fromkeys(MOVING_OPTIONS, False)}
            _, plain = load_and_retarget(Path(path), robot, None, unmoved, skeleton_map, **variant)
            entry["target_adjustment"] = target_adjustment(plain, targets)
        report = check_targets(_arms_model(robot), targets) if ik_check else None
        mask = None
        for label, algo, wo, extra in runs:
            bar.set_postfix_str(f"{clip.name[:28]} {label}")
            try:
                tr = run_algorithm(
                    robot,
                    targets,
                    algo,
                    qp=args.qp,
                    rate=args.rate,
                    sim=sim,
                    settle=settle,
                    solver=extra,
                    wqp_weights=wqp_weights,
                    wrist_only=wo,
                )
                if algo == REFERENCE_ALGO and not wo:
                    mask = reachable_mask(tr)
                if algo in algos or wrist_only:
                    entry["algos"][label] = trace_metrics(tr, robot, mask, report, sim=sim)
                    if plain is not None:
                        entry["algos"][label] |= operator_errors(tr, plain)
                    if op_waist is not None:
                        entry["algos"][label] |= waist_vs_operator(tr, robot, op_waist)
                    traces[(clip.name, label)] = tr
            except Exception as exc:  # one failed run must not lose the others' results
                log.error(
                    "%s on %s failed: %s: %s",
                    label,
                    clip.name,
                    type(exc).__name__,
                    exc,
                    exc_info=log.isEnabledFor(logging.DEBUG),
                )
                failed.append({"clip": clip.name, "algo": label, "error": f"{type(exc).__name__}: {exc}"})
            bar.update(1)
        entry["hqp_vs"] = compare(entry, REFERENCE_ALGO) if REFERENCE_ALGO in algos else {}
        goals = clip_goals(entry["algos"], bars)
        if goals is not None:
            # what held the arms on the ticks over each missed goal's bar (or behind the peer's errors)
            explain_misses(goals, {a: traces[(clip.name, a)] for a in algos if (clip.name, a) in traces}, robot, report)
            entry["goals"] = goals
        clips_out.append(entry)
    bar.close()
    if not clips_out:
        raise SystemExit(f"mimic eval: no clip could be evaluated ({len(skipped)} skipped, see above)")
    result = {
        "clips": clips_out,
        "skipped": skipped,
        "failed": failed,
        "summary": summarise(clips_out) | {"hqp_vs": _compare_summary(clips_out)} | _adjustment_summary(clips_out),
        "paper": PAPER,
    }
    if any("goals" in c for c in clips_out):
        result["summary"]["goals"] = goals_summary({c["clip"]: c.get("goals") for c in clips_out})
    result["settings"] = _settings_json(
        args, algos, solver, wqp_weights, retarget, robot.nq, robot.profile.max_joint_velocity
    )
    result["settings"] |= {
        "skeleton_map": skeleton_map,
        "clip_variant": variant,
        "goals_file": getattr(args, "goals", None),
        "ik_check": {"wrist_tol_m": IK_TOL, "pair_tol_m": PAIR_TOL} if ik_check else None,
    }
    return result, traces


def _adjustment_summary(clips: list[dict]) -> dict:
    """``target_adjustment`` over clips (empty without a :data:`MOVING_OPTIONS` option): the arm-frame weighted
    mean, the worst clip's p99 and the largest max, per quantity."""
    rows = [c["target_adjustment"] for c in clips if c.get("target_adjustment", {}).get("arm_frames")]
    if not rows:
        return {}
    out = {}
    for key in ("wrist_cm", "elbow_cm", "wrist_rot_deg"):
        w = [r["arm_frames"] for r in rows]
        out[key] = {
            "mean": float(sum(r[key]["mean"] * n for r, n in zip(rows, w, strict=True)) / sum(w)),
            "p99": max(r[key]["p99"] for r in rows),
            "max": max(r[key]["max"] for r in rows),
        }
    return {"target_adjustment": out}


def _compare_summary(clips: list[dict]) -> dict:
    """Over clips: on how many the HQP's elbow mean is within 0.05 cm of (or below) each other algorithm's,
    and its wrist mean below."""
    out: dict = {}
    for c in clips:
        for algo, row in c.get("hqp_vs", {}).items():
            o = out.setdefault(algo, {"clips": 0, "hqp_elbow_better": 0, "hqp_wrist_better": 0})
            o["clips"] += 1
            o["hqp_elbow_better"] += int(row["hqp_elbow_better"])
            o["hqp_wrist_better"] += int(row["hqp_wrist_better"])
    return out


def _settings(args: argparse.Namespace) -> tuple[list[str], dict, tuple[float, ...] | None, dict]:
    """(algorithms, SolverConfig fields, wqp weights or None, RetargetConfig fields) from the flags;
    ``--paper`` sets the paper's mapping, orientation level 1, mapped elbows with their orientations on
    level 2 (the elbow pose), eq. 4 against the rest pose, no trunk push and no saturation trade. The retargeter
    otherwise runs with the service's own settings (``RetargetConfig``)."""
    algos = [a.strip() for a in args.algos.split(",") if a.strip()]
    unknown = [a for a in algos if a not in ALGORITHMS and a not in PEERS]
    if unknown:
        raise SystemExit(f"unknown algorithms {unknown}; known: {[*sorted(ALGORITHMS), *PEERS]}")
    if any(a in PEERS for a in algos):
        try:
            require_mink()
        except MinkMissingError as exc:
            raise SystemExit(str(exc)) from None
    defaults = RetargetConfig()
    level = getattr(args, "wrist_orientation_level", None)
    elbows = getattr(args, "elbow_placement", defaults.elbow_placement)
    mapping = getattr(args, "mapping", defaults.mode)
    wrist_only = getattr(args, "wrist_only", False)
    if getattr(args, "posture_policy", None) and not wrist_only:
        raise SystemExit("--posture-policy is used with --wrist-only (with full targets the solver does not use it)")
    oref = getattr(args, "orientation_reference", None) or ("posture" if wrist_only else defaults.orientation_reference)
    paper = getattr(args, "paper", False)
    if paper:
        level, elbows, oref, mapping = 1, "mapped", "rest", "paper"
    solver = {} if level is None else {"wrist_orientation_level": level}
    if paper:
        solver["wrist_orientation_cost"] = PAPER_ORIENTATION_COST
    saturation = getattr(args, "saturation_weight", None)
    if saturation is None and paper:
        saturation = 0.0  # the paper's hierarchy is strict on every tick, a saturated one too
    if saturation is not None:
        solver["saturation_weight"] = saturation
    for field in ("waist_follow_cost", "waist_damping_cost"):
        if getattr(args, field, None) is not None:
            solver[field] = getattr(args, field)
    trigger = getattr(args, "saturation_trigger", None)
    if trigger is not None:
        solver["saturation_trigger"] = trigger
    solver |= switch_values(args, EVAL_SWITCHES)
    wq = getattr(args, "wqp_weights", None)
    wqp_weights = tuple(float(w) for w in wq.split(",")) if wq else None
    # The paper's elbow pose: elbow orientations published (use_rotation) and tracked on level 2.
    retarget = {"mode": mapping, "elbow_placement": elbows, "orientation_reference": oref, "elbow_rotation": paper}
    retarget["velocity_tau"] = getattr(args, "velocity_tau", defaults.velocity_tau)
    for k in RETARGET_SWITCHES:
        retarget[k] = getattr(args, k, getattr(defaults, k))
    retarget["trunk_clearance_fast"] = getattr(args, "trunk_clearance_fast", defaults.trunk_clearance_fast)
    if paper:
        retarget["trunk_clearance"] = False  # the paper publishes its eqs. 1-3 as they are
    # The operator's upper arm (seed 004) only where something reads it: it costs ~2 ms per frame.
    retarget["upper_arms"] = wrist_only or "clik-mimicry" in algos
    return algos, solver, wqp_weights, retarget


def _settings_json(
    args: argparse.Namespace,
    algos: list[str],
    solver: dict,
    wqp_weights: tuple[float, ...] | None,
    retarget: dict,
    dof: int,
    max_joint_velocity: float,
) -> dict:
    """What ran, for the result JSON (anyone can rerun it from these)."""
    return {
        "algos": algos,
        "qp": args.qp,
        "rate_hz": args.rate,
        "mapping": retarget["mode"],
        "retarget": retarget,
        "wqp_weights": list(wqp_weights) if wqp_weights else "default (1.0, 0.3, 1.0)",
        # every SolverConfig field the runs used (the shipped defaults unless a flag changed one)
        "solver": asdict(SolverConfig(**solver)),
        "dof": dof,
        "max_joint_velocity": max_joint_velocity,
        "wrist_only": getattr(args, "wrist_only", False),
        "posture_policy": getattr(args, "posture_policy", None),
        "sim": not args.no_sim,
        "settle_s": getattr(args, "settle", SETTLE),
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
    if "goals" in result["summary"]:
        for line in goals_lines(result["summary"]["goals"]):
            log.info("%s", line)
    log.info("wrote %s in %.1f s", out, result["settings"]["wall_s"])
    if result["failed"]:
        log.error("%d run(s) failed; the others are in %s, the failures under 'failed'", len(result["failed"]), out)
        return 1
    return 0
