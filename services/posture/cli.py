"""``mimic posture train|bench|gate``: the learned posture policy (seed 004 section 3).

    mimic posture train CLIPS... --out FILE [--relabel-rounds N] --json REPORT [--plot PNG]
    mimic posture bench --policy FILE [--ticks N]                # = mimic bench posture: inference cost, JSON
    mimic posture gate --policy FILE CLIP                        # gate in and out of distribution, JSON

``train`` splits the clips by clip (sorted by name, every ``--holdout-every``-th held out for the
report), runs Algorithm 1 against plain BC at equal demonstration time and writes the relabelled
policy (numpy weights + metadata), the report JSON and the learning-curve PNG.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from shared.targets import SIDES

log = logging.getLogger("mimic.posture")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from services.posture.train import ELBOW_AUGMENT_DEG, TrainConfig  # numpy only (torch is imported when training)

    sub = parser.add_subparsers(dest="posture_command", metavar="ACTION", required=True)
    t = sub.add_parser("train", help="train the policy (BC + online relabelling) on clips; needs mimic[train]")
    t.add_argument("clips", nargs="+", help="BVH/C3D clips (split by clip into train and held-out test)")
    t.add_argument("--out", required=True, help="model file to write (.npz)")
    t.add_argument("--json", required=True, help="training report JSON")
    t.add_argument("--plot", default=None, help="learning-curve PNG (default: next to --json, *_curve.png)")
    t.add_argument("--relabel-rounds", type=int, default=2, help="Algorithm 1 rounds after pre-training")
    t.add_argument("--holdout-every", type=int, default=4, help="every k-th clip (sorted by name) is held out")
    t.add_argument("--holdout-fold", type=int, default=None,
                   help="which of the --holdout-every folds is held out, 0-based (default: the last, k - 1); "
                        "folds 0..k-1 together hold every clip out once (cross-validation)")  # fmt: skip
    t.add_argument("--pretrain-fraction", type=float, default=0.4, help="share of demonstration time before round 1")
    t.add_argument("--chunk-s", type=float, default=10.0, help="demonstration chunk length [s]")
    t.add_argument("--eps", type=float, default=0.0, help="Algorithm 1 threshold on ||a - a_hat||^2 [(rad/s)^2]")
    t.add_argument("--hidden", type=int, default=128, help="encoder hidden units per layer")
    t.add_argument("--encoder-layers", type=int, default=TrainConfig.encoder_layers, help="encoder hidden layers")
    t.add_argument("--decoder-hidden", type=int, default=32, help="decoder hidden units per layer (it feeds the gate)")
    t.add_argument("--decoder-layers", type=int, default=1, help="decoder hidden layers")
    t.add_argument("--epochs", type=int, default=80, help="training epochs per fit (chosen on validation clips)")
    t.add_argument("--input-noise", type=float, default=0.0,
                   help="std of the noise on the encoder's normalised inputs in training (regulariser)")  # fmt: skip
    t.add_argument("--augment-deg", type=float, default=None,
                   help="elbow kind: also train the encoder on each sample's whole arm turned about the shoulder "
                   f"by a random yaw and pitch within this many degrees, fresh every epoch (0: off; default: "
                   f"{ELBOW_AUGMENT_DEG:g} for the elbow kind, 0 for the others)")  # fmt: skip
    t.add_argument("--augment-pitch-deg", type=float, default=None,
                   help="pitch bound of those turns [deg] (default: --augment-deg; 0: yaw only)")  # fmt: skip
    t.add_argument("--augment-reach", type=float, default=0.0,
                   help="elbow kind: the augmented copies' shoulder-wrist distance also scaled by 1 +- this "
                   "(the elbow kept on the circle that reaches the wrist; 0: off)")  # fmt: skip
    t.add_argument("--weight-decay", type=float, default=0.0, help="AdamW weight decay (0: plain Adam)")
    t.add_argument("--temporal-weight", type=float, default=0.0,
                   help="lambda of a loss term on consecutive ticks of a rollout: the prediction's change minus "
                   "the label's change, squared (normalised actions; 0: off)")  # fmt: skip
    t.add_argument("--temporal-ticks", type=int, default=1,
                   help="the pairs of --temporal-weight: this many rollout ticks apart (1: consecutive)")  # fmt: skip
    t.add_argument("--gate-factor", type=float, default=TrainConfig.gate_factor,
                   help="gate threshold per arm = this x the 99th percentile of the training gaps |x_dv - p| "
                   "(chosen on validation clips, see TrainConfig)")  # fmt: skip
    t.add_argument("--seed", type=int, default=0, help="seed of everything random")
    t.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    t.add_argument("--rate", type=float, default=50.0, help="closed-loop CLIK rate of the rollouts [Hz]")
    t.add_argument("--action-kind", choices=("elbow", "swivel", "posture", "velocity"), default="elbow",
                   help="elbow: the encoder gives the operator's elbow from the hand pose, tracked by the solver's "
                   "elbow task; swivel: the elbow's angle on the circle that reaches the wrist, placed there for "
                   "that task; posture: the operator's shoulder posture q*, driven as q0dot = K (q* - q); "
                   "velocity: the paper's q0dot (label -eta grad H)")  # fmt: skip
    t.add_argument("--action-gain", type=float, default=None,
                   help="K [1/s] of the posture kind and of the elbow kind's rollouts (default 20)")  # fmt: skip
    t.add_argument("--no-mirror", dest="mirror", action="store_false",
                   help="do not add each arm's demonstrations, mirrored, to the other arm's")  # fmt: skip
    c = sub.add_parser("cv", help="k-fold cross-validation by clip: train each fold, score its held-out clips, pool")
    c.add_argument("clips", nargs="+", help="BVH/C3D clips (every clip is held out once)")
    c.add_argument("--out-dir", required=True, help="folder for the models, training reports and eval JSONs")
    c.add_argument("--json", default=None, help="also write the report here (it is always in OUT_DIR/cv.json)")
    c.add_argument("--folds", type=int, default=4, help="k: the folds of --holdout-every k")
    c.add_argument("--seeds", default="0,1,2", help="training seeds, comma list (the pooled figures are per seed)")
    c.add_argument("--train-args", default="", help="extra flags for every 'mimic posture train' (quoted)")
    c.add_argument("--eval-args", default="", help="extra flags for every 'mimic eval' (quoted)")
    c.add_argument("--resume", action="store_true",
                   help="reuse the models in OUT_DIR (an interrupted run, same --train-args)")  # fmt: skip
    from services.posture import bench

    bench.add_arguments(sub.add_parser("bench", help="time the numpy inference of one tick (both arms), JSON"))
    g = sub.add_parser("gate", help="gate on a clip's states and on out-of-distribution targets, JSON")
    g.add_argument("clip", help="held-out clip")
    g.add_argument("--policy", required=True, help="model file")
    g.add_argument("--json", default=None, help="also write the JSON here")


def split_clips(clips: list[str], every: int, fold: int | None = None) -> tuple[list[str], list[str]]:
    """(train, test) by clip: sorted by file name, the clips at 0-based positions ``i`` with ``i % every == fold``
    held out (default fold ``every - 1``: every ``every``-th clip, 1-based). Folds ``0 .. every - 1`` hold every clip
    out exactly once.

    Raises:
        ValueError: fold outside ``0 .. every - 1``.
    """
    paths = sorted(clips, key=lambda p: Path(p).name)
    if every < 2:
        return paths, []
    fold = every - 1 if fold is None else fold
    if not 0 <= fold < every:
        raise ValueError(f"--holdout-fold must be in 0..{every - 1} for --holdout-every {every}, got {fold}")
    test = [p for i, p in enumerate(paths) if i % every == fold]
    return [p for p in paths if p not in test], test


def gate_thresholds(weights: dict, meta: dict, data, factor: float, floor: float | None = None) -> dict:
    """Per side: ``factor`` times the 99th percentile of |x_dv - p| [m] over the states ``data.S``
    (the training states), at least ``floor`` [m] (default :data:`GATE_MIN`).

    Returns ``{"gate_threshold": {side: m}, "gate_stats": {side: {gap_p50_m, gap_p99_m, factor, threshold_m}}}``.
    """
    floor = GATE_MIN if floor is None else floor
    from services.posture.features import decoder_input
    from services.posture.policy import _layers, mlp

    out = {}
    stats = {}
    for i, s in enumerate(SIDES):
        S = data.S[i]
        a = mlp(_layers(weights, f"{s}.enc"), S)
        z = mlp(_layers(weights, f"{s}.dec"), decoder_input(a, S))
        from services.posture.features import ArmFrame, virtual_target

        arm = ArmFrame(np.asarray(meta["arms"][s]["centre"]), meta["arms"][s]["upper"], meta["arms"][s]["fore"])
        gap = np.linalg.norm(virtual_target(arm, z) - S[:, 4:7], axis=1)
        p99 = float(np.percentile(gap, 99))
        out[s] = max(factor * p99, floor)
        stats[s] = {"gap_p50_m": float(np.median(gap)), "gap_p99_m": p99, "factor": factor, "threshold_m": out[s]}
    return {"gate_threshold": out, "gate_stats": stats}


#: The gate threshold is never below this [m] (the factor is ``TrainConfig.gate_factor``).
GATE_MIN = 0.03


def _train(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from services.posture.features import ACTION_LAYOUTS, ARM_STATE_LAYOUT, HAND_INPUTS, STATE_LAYOUT, action_dim
    from services.posture.policy import save_policy
    from services.posture.relabel import ExperimentConfig, relabel_experiment
    from services.posture.rollout import POSTURE_RETARGET, ArmsModel, RolloutConfig, prepare_clip
    from services.posture.train import ELBOW_AUGMENT_DEG, TrainConfig, require_torch
    from shared.robot.pinocchio_model import build_robot_model

    if args.augment_deg is None:
        args.augment_deg = ELBOW_AUGMENT_DEG if args.action_kind == "elbow" else 0.0
    if (args.augment_deg > 0.0 or args.augment_reach > 0.0) and args.action_kind != "elbow":
        raise SystemExit("--augment-deg/--augment-reach move elbow labels: they need --action-kind elbow")
    try:
        train_paths, test_paths = split_clips(args.clips, args.holdout_every, args.holdout_fold)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    torch = require_torch()
    t_start = time.perf_counter()
    np.random.seed(args.seed)
    if not train_paths:
        raise SystemExit("no training clips left after the hold-out")
    robot = build_robot_model(with_waist=False)
    arms = ArmsModel(robot)
    clips = {}
    for p in tqdm(train_paths + test_paths, desc="retarget", unit="clip", file=sys.stderr):
        clips[p] = prepare_clip(p, robot)
    train = [clips[p] for p in train_paths]
    test = [clips[p] for p in test_paths] or train[-1:]
    posture = args.action_kind != "velocity"  # posture and elbow: labels from the hand pose alone
    tcfg = TrainConfig(hidden=args.hidden, decoder_hidden=args.decoder_hidden, decoder_layers=args.decoder_layers,
                       epochs=args.epochs, seed=args.seed, threads=args.threads, hand_only=posture,
                       input_noise=args.input_noise, gate_factor=args.gate_factor,
                       unit_action=args.action_kind == "swivel", augment_deg=args.augment_deg,
                       augment_pitch_deg=args.augment_pitch_deg, augment_reach=args.augment_reach,
                       encoder_layers=args.encoder_layers, weight_decay=args.weight_decay,
                       temporal_weight=args.temporal_weight, temporal_ticks=args.temporal_ticks)  # fmt: skip
    rcfg = RolloutConfig(rate=args.rate, action_kind=args.action_kind)
    if args.action_gain is not None:
        rcfg.action_gain = args.action_gain
    ecfg = ExperimentConfig(chunk_s=args.chunk_s, pretrain_fraction=args.pretrain_fraction,
                            rounds=args.relabel_rounds, eps=args.eps, seed=args.seed, mirror=args.mirror)  # fmt: skip
    base_meta = {
        "robot": robot.profile.name,
        "sides": list(SIDES),
        "state_layout": list(STATE_LAYOUT),
        "action_layout": list(ACTION_LAYOUTS[args.action_kind]),
        "action_joints": {s: [robot.joint_names[j] for j in arms.act[i]] for i, s in enumerate(SIDES)},
        "arm_joints": {s: [robot.joint_names[j] for j in arms.arm[i]] for i, s in enumerate(SIDES)},
        "arm_state_layout": list(ARM_STATE_LAYOUT),
        "arms": {s: arms.frames[i].to_dict() for i, s in enumerate(SIDES)},
        "q_ref": {s: [float(x) for x in arms.Q_ref[i]] for i, s in enumerate(SIDES)},
        "action_kind": args.action_kind,
        "posture_gain": rcfg.action_gain if posture else 0.0,
        "encoder_inputs": list(STATE_LAYOUT[:HAND_INPUTS] if posture else STATE_LAYOUT),
        "mirror_signs": [float(x) for x in arms.mirror] if args.mirror else None,
        "network": {
            "encoder": [14, *[tcfg.hidden] * tcfg.encoder_layers, action_dim(args.action_kind)],
            "decoder": [14 + action_dim(args.action_kind), *[tcfg.decoder_hidden] * tcfg.decoder_layers, 6],
            "activation": "tanh (input and hidden layers), linear output",
        },
        "train_clips": [Path(p).name for p in train_paths],
        "test_clips": [Path(p).name for p in test_paths],
        "clips_sha256": {Path(p).name: hashlib.sha256(Path(p).read_bytes()).hexdigest()[:16] for p in train_paths},
        "retarget": POSTURE_RETARGET,
        "rollout": asdict(rcfg),
        "train": asdict(tcfg),
        "experiment": asdict(ecfg),
        "torch": torch.__version__,
    }
    if args.action_kind == "swivel":  # each arm's circle and angle reference
        for i, s in enumerate(SIDES):
            base_meta["arms"][s]["swivel"] = arms.swivel[i].to_dict()

    def make_meta(weights, data):
        meta = dict(base_meta)
        meta.update(gate_thresholds(weights, meta, data, tcfg.gate_factor))
        return meta

    def epoch_done(side: str, epoch: int, losses: tuple[float, float]) -> None:
        if (epoch + 1) % 10 == 0 or epoch + 1 == tcfg.epochs:
            log.info(
                "  fit %s: epoch %d/%d, losses %.3g (action) %.3g (decoder)", side, epoch + 1, tcfg.epochs, *losses
            )

    weights, report, data = relabel_experiment(
        arms, train, test, make_meta, ecfg, tcfg, rcfg, progress=lambda m: log.info("%s", m), fit_progress=epoch_done
    )
    meta = make_meta(weights, data)
    meta["samples"] = len(data)
    meta["train_wall_s"] = time.perf_counter() - t_start
    out = save_policy(args.out, weights, meta)
    report["model"] = {"path": str(out), "bytes": out.stat().st_size, "gate": meta["gate_stats"]}
    report["train_clips"], report["test_clips"] = meta["train_clips"], meta["test_clips"]
    report["wall_s"] = meta["train_wall_s"]
    jpath = Path(args.json)
    jpath.parent.mkdir(parents=True, exist_ok=True)
    jpath.write_text(json.dumps(report, indent=2))
    plot = Path(args.plot) if args.plot else jpath.with_name(jpath.stem + "_curve.png")
    from services.posture.plots import learning_curve

    learning_curve(report, plot)
    summary = {k: report[k] for k in ("relabel", "bc", "expert_test", "wall_s")}
    summary["model"], summary["plot"] = str(out), str(plot)
    sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    return 0


def _gate(args: argparse.Namespace) -> int:
    from services.posture.gate_check import gate_report

    out = gate_report(args.clip, args.policy)
    text = json.dumps(out, indent=2)
    if args.json:
        Path(args.json).write_text(text)
    sys.stdout.write(text + "\n")
    return 0


def _cv(args: argparse.Namespace) -> int:
    from services.posture.cv import run_cv

    if args.folds < 2:
        raise SystemExit(f"--folds must be at least 2, got {args.folds}")
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        raise SystemExit(f"--seeds must be a comma list of integers, got {args.seeds!r}") from None
    try:
        report = run_cv(args.clips, Path(args.out_dir), args.folds, seeds, args.train_args, args.eval_args, args.resume)
    except RuntimeError as e:
        raise SystemExit(str(e)) from None
    text = json.dumps({k: report[k] for k in ("folds", "seeds", "pooled", "pooled_mean")}, indent=2)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
    sys.stdout.write(text + "\n")
    return 0


def main(args: argparse.Namespace) -> int:
    from services.posture import bench

    return {"train": _train, "cv": _cv, "bench": bench.main, "gate": _gate}[args.posture_command](args)
