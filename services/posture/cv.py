"""``mimic posture cv``: k-fold cross-validation by clip of the shipped training, scored by ``mimic eval``.

Issue 16's goal is measured on clips the policy was not trained on. One split of 5 clips moved by 0.4 cm with the
seed alone; here every clip is held out exactly once (``split_clips`` folds 0..k-1, ``--holdout-fold``), each fold's
model is trained by ``mimic posture train`` and its held-out clips are scored by ``mimic eval --wrist-only
--posture-policy`` (full mocap, wrist-only with the rest posture, wrist-only with the policy), and the elbow and wrist
means are pooled over all clips weighted by their ticks, per seed. Both commands run as subprocesses, exactly as a
user runs them (the shipped defaults unless ``--train-args`` says otherwise).
"""

from __future__ import annotations

import json
import logging
import shlex
import subprocess
import sys
from pathlib import Path

log = logging.getLogger("mimic.posture")

#: The three ``mimic eval --wrist-only --posture-policy`` runs per clip, by their JSON labels.
RUNS = {"full": "full:hqp-nullspace", "rest": "wrist-only:hqp-nullspace", "policy": "wrist-only+policy:hqp-nullspace"}


def pool(evals: list[dict]) -> dict:
    """Tick-weighted elbow and wrist means [cm] of the three runs over the clips of ``evals`` (``mimic eval`` JSON
    reports, e.g. one per fold of one seed), with the policy's ratios to the rest posture and to full mocap.

    Raises:
        KeyError: a report without the three wrist-only runs.
    """
    acc = {k: [0.0, 0.0] for k in RUNS}  # run -> [elbow * ticks, wrist * ticks]
    ticks = 0.0
    for ev in evals:
        for clip in ev["clips"]:
            algos = clip["algos"]
            n = float(algos[RUNS["full"]]["ticks"])
            for k, label in RUNS.items():
                acc[k][0] += algos[label]["elbow_err_cm"]["mean"] * n
                acc[k][1] += algos[label]["wrist_err_cm"]["mean"] * n
            ticks += n
    out: dict = {"ticks": int(ticks), "clips": sum(len(ev["clips"]) for ev in evals)}
    for k in RUNS:
        out[f"{k}_elbow_cm"] = acc[k][0] / ticks
        out[f"{k}_wrist_cm"] = acc[k][1] / ticks
    out["policy_over_rest"] = out["policy_elbow_cm"] / out["rest_elbow_cm"]
    out["policy_over_full"] = out["policy_elbow_cm"] / out["full_elbow_cm"]
    return out


def run_cv(
    clips: list[str],
    out_dir: Path,
    folds: int,
    seeds: list[int],
    train_args: str = "",
    eval_args: str = "",
    resume: bool = False,
) -> dict:
    """Train and score every (fold, seed); returns the report (also written to ``out_dir/cv.json``).

    Args:
        clips: BVH/C3D paths (the folds are ``split_clips``').
        out_dir: models, training reports and eval JSONs go here (``f<fold>_s<seed>``).
        folds: k of the k-fold split (``--holdout-every``).
        seeds: training seeds; the pooled figures are per seed.
        train_args, eval_args: extra flags for every ``mimic posture train`` / ``mimic eval`` call (shell syntax).
        resume: reuse a fold's model when its file exists (an interrupted run); otherwise every model is trained
            anew, so a changed ``train_args`` never meets a stale model.

    Raises:
        RuntimeError: a train or eval run failed (its last output lines in the message).
    """
    from services.posture.cli import split_clips

    out_dir.mkdir(parents=True, exist_ok=True)
    mimic = [sys.executable, "-m", "services.cli"]
    runs = []
    reports: dict[int, list[dict]] = {seed: [] for seed in seeds}  # seed -> its folds' eval reports
    for fold in range(folds):
        test = split_clips(clips, folds, fold)[1]
        for seed in seeds:
            tag = out_dir / f"f{fold}_s{seed}"
            model, ev = tag.with_suffix(".npz"), tag.with_name(tag.name + "_eval.json")
            if not (resume and model.exists()):
                _run([*mimic, "posture", "train", *clips, "--holdout-every", str(folds), "--holdout-fold", str(fold),
                      "--seed", str(seed), "--out", str(model), "--json", str(tag.with_name(tag.name + "_train.json")),
                      *shlex.split(train_args)], f"posture train, fold {fold}, seed {seed}")  # fmt: skip
            _run([*mimic, "eval", *test, "--wrist-only", "--posture-policy", str(model), "--algos", "hqp-nullspace",
                  "--no-sim", "--json", str(ev), *shlex.split(eval_args)],
                 f"eval, fold {fold}, seed {seed}")  # fmt: skip
            reports[seed].append(json.loads(ev.read_text()))
            names = [Path(p).name for p in test]
            runs.append({"fold": fold, "seed": seed, "test_clips": names, **pool(reports[seed][-1:])})
            log.info("fold %d seed %d: policy elbow %.3f cm (%.3fx rest)", fold, seed, runs[-1]["policy_elbow_cm"],
                     runs[-1]["policy_over_rest"])  # fmt: skip
    pooled = {str(seed): pool(reports[seed]) for seed in seeds}
    means = {k: sum(p[k] for p in pooled.values()) / len(pooled) for k in ("policy_elbow_cm", "policy_over_rest",
                                                                              "policy_over_full")}  # fmt: skip
    report = {"folds": folds, "seeds": seeds, "train_args": train_args, "runs": runs, "pooled": pooled,
              "pooled_mean": means}  # fmt: skip
    (out_dir / "cv.json").write_text(json.dumps(report, indent=2))
    return report


def _run(cmd: list[str], what: str) -> None:
    """Run one mimic command (``what`` names it in the log); its output is kept only when it fails."""
    log.info("mimic %s", what)
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        tail = "\n".join((res.stderr or res.stdout).strip().splitlines()[-5:])
        raise RuntimeError(f"mimic {what} failed (exit {res.returncode}):\n{tail}")
