"""Algorithm 1 (online relabelling) against plain behaviour cloning at equal demonstration time.

The training clips are cut into demonstration chunks of ``chunk_s`` seconds, shuffled once (seeded).
Demonstration time is counted in chunk seconds, as seed 004 counts teleoperation minutes.

- Relabelling: the expert drives the first ``pretrain_fraction`` of the time (the pre-training set D,
  policy π₀ = BC on D). Each of ``rounds`` rounds then runs the current policy in closed loop on the
  next chunks; the expert labels every visited state, states where ``||a - â||² >= eps`` form D_E,
  ``D <- D ∪ D_E`` and the policy is retrained on D (lines 1-15).
- Plain BC: for every cumulative time of the relabelling schedule, the expert drives all of it and BC
  trains on those samples.

Both are scored in closed loop on held-out clips: the policy drives, and the expert's labels along
the policy's own trajectory give the action error; the elbow error is against the reference elbow.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from services.posture.policy import PosturePolicy
from services.posture.rollout import ArmsModel, ClipData, Rollout, RolloutConfig, rollout
from services.posture.train import Dataset, TrainConfig, fit, from_rollouts

log = logging.getLogger("mimic.posture")


@dataclass
class ExperimentConfig:
    """Schedule of the comparison.

    Attributes:
        chunk_s: demonstration chunk length [s]. pretrain_fraction: share of the training time the
        expert demonstrates before the first round. rounds: relabelling rounds (n_round).
        eps: Algorithm 1's threshold on ``||a - â||²`` [(rad/s)²]. seed: chunk order.
        mirror: every fit also learns each arm from the other arm's samples reflected through the
            sagittal plane (:meth:`.train.Dataset.with_mirror`), twice the demonstrations per arm.
            Sample counts in the report are before mirroring.
    """

    chunk_s: float = 10.0
    pretrain_fraction: float = 0.4
    rounds: int = 2
    eps: float = 0.0
    seed: int = 0
    mirror: bool = True


def chunks(clips: list[ClipData], chunk_s: float, seed: int) -> list[ClipData]:
    """Clips cut into pieces of about ``chunk_s`` seconds, in a seeded random order."""
    out = []
    for c in clips:
        n = max(1, round(c.duration / chunk_s))
        edges = np.linspace(0, len(c.t), n + 1).astype(int)
        out += [c.slice(a, b) for a, b in itertools.pairwise(edges) if b - a > 2]
    order = np.random.default_rng(seed).permutation(len(out))
    return [out[i] for i in order]


def score(arms: ArmsModel, policy: PosturePolicy, test: list[ClipData], rcfg: RolloutConfig) -> dict:
    """Closed-loop scores of a policy on clips (policy drives, no gate): action MSE, elbow/wrist error."""
    rolls = [rollout(arms, c, "policy", policy, rcfg) for c in test]
    return summarise(rolls, on_policy=True)


def summarise(rolls: list[Rollout], on_policy: bool) -> dict:
    """Mean action MSE [(rad/s)²] (policy vs expert label, when the policy drove), elbow and wrist error [cm]."""
    ok = np.concatenate([r.label_ok for r in rolls])
    ee = np.concatenate([r.elbow_err for r in rolls])
    we = np.concatenate([r.wrist_err for r in rolls])
    out = {"elbow_err_cm": float(100 * np.nanmean(ee)), "wrist_err_cm": float(100 * np.nanmean(we))}
    if on_policy:
        d = np.concatenate([((r.A - r.A_pi) ** 2).sum(-1) for r in rolls])
        out["action_mse"] = float(d[ok].mean())
    return out


def relabel_experiment(
    arms: ArmsModel,
    train: list[ClipData],
    test: list[ClipData],
    make_meta: Callable[[dict, Dataset], dict],
    cfg: ExperimentConfig | None = None,
    tcfg: TrainConfig | None = None,
    rcfg: RolloutConfig | None = None,
    progress: Callable[[str], None] | None = None,
    fit_progress: Callable[[str, int, tuple[float, float]], None] | None = None,
) -> tuple[dict[str, np.ndarray], dict, Dataset]:
    """Run Algorithm 1 and the BC comparison; returns (final relabelled weights, report, final D).

    Args:
        make_meta: (weights, dataset) -> model metadata (gate thresholds etc.), so intermediate
            policies can be run in closed loop.
        progress: called with a line per stage. fit_progress: called per epoch of every fit
            (side, epoch, (action loss, decoder loss)).
    """
    cfg = cfg or ExperimentConfig()
    tcfg = tcfg or TrainConfig()
    rcfg = rcfg or RolloutConfig()
    say = progress or (lambda msg: log.info("%s", msg))
    pieces = chunks(train, cfg.chunk_s, cfg.seed)
    dur = np.array([p.duration for p in pieces])
    total = float(dur.sum())
    budgets = [cfg.pretrain_fraction * total + r * (1 - cfg.pretrain_fraction) * total / max(cfg.rounds, 1)
               for r in range(cfg.rounds + 1)]  # fmt: skip
    ends = [int(np.searchsorted(np.cumsum(dur), b - 1e-9) + 1) for b in budgets]
    ends[-1] = len(pieces)
    t0 = time.perf_counter()
    expert_rolls: dict[int, Rollout] = {}

    def expert(j: int) -> Rollout:
        if j not in expert_rolls:
            expert_rolls[j] = rollout(arms, pieces[j], "expert", None, rcfg)
        return expert_rolls[j]

    def train_policy(data: Dataset, tag: str):
        if cfg.mirror:
            data = data.with_mirror(arms.mirror, rcfg.action_kind)
        w, rep = fit(data, tcfg, fit_progress, frames=arms.frames)
        pol = PosturePolicy(w, make_meta(w, data))
        say(f"{tag}: trained on {len(data)} samples")
        return w, rep, pol

    report: dict = {"config": asdict(cfg), "chunks": len(pieces), "train_seconds": total, "bc": [], "relabel": []}
    # Expert in closed loop on the test clips: the reference the policies imitate.
    report["expert_test"] = summarise([rollout(arms, c, "expert", None, rcfg) for c in test], on_policy=False)
    # ---- Algorithm 1
    say(f"pre-training on {ends[0]} chunks ({sum(dur[: ends[0]]):.0f} s of demonstration)")
    D = from_rollouts([expert(j) for j in range(ends[0])])
    w, rep, pol = train_policy(D, "relabel round 0 (= BC)")
    rows = [{"round": 0, "demo_s": float(dur[: ends[0]].sum()), "samples": len(D), "added": len(D),
             **score(arms, pol, test, rcfg)}]  # fmt: skip
    say(f"round 0: {rows[-1]}")
    for r in range(1, cfg.rounds + 1):
        rolls = [rollout(arms, pieces[j], "policy", pol, rcfg) for j in range(ends[r - 1], ends[r])]
        D_E = from_rollouts(rolls, only="disagree", eps=cfg.eps)
        D = D.add(D_E.S, D_E.A, D_E.Z, D_E.nxt)
        w, rep, pol = train_policy(D, f"relabel round {r}")
        rows.append({"round": r, "demo_s": float(dur[: ends[r]].sum()), "samples": len(D), "added": len(D_E),
                     **score(arms, pol, test, rcfg)})  # fmt: skip
        say(f"round {r}: {rows[-1]}")
    report["relabel"] = rows
    final_w, final_rep, final_D = w, rep, D
    # ---- plain BC at the same demonstration times
    report["bc"].append({**rows[0], "round": None})
    for r in range(1, cfg.rounds + 1):
        Db = from_rollouts([expert(j) for j in range(ends[r])])
        _w, _rep, polb = train_policy(Db, f"BC at {dur[: ends[r]].sum():.0f} s")
        report["bc"].append({"round": None, "demo_s": float(dur[: ends[r]].sum()), "samples": len(Db),
                             **score(arms, polb, test, rcfg)})  # fmt: skip
        say(f"BC {r}: {report['bc'][-1]}")
    report["final_train"] = final_rep
    report["wall_s"] = time.perf_counter() - t0
    return final_w, report, final_D
