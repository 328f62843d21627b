"""``mimic bench posture --policy FILE``: cost of the numpy posture inference per control tick (JSON).

One tick = :meth:`~services.posture.policy.PosturePolicy.act` for both arms: encoder, decoder,
virtual target and gate, as the solver calls it. The budget is 0.05 ms.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

BUDGET_US = 50.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy", required=True, help="model file (mimic posture train)")
    p.add_argument("--ticks", type=int, default=20000, help="ticks to time")
    p.add_argument("--json", default=None, help="also write the JSON here")


def main(args: argparse.Namespace) -> int:
    from services.posture.policy import PosturePolicy

    pol = PosturePolicy.load(args.policy)
    rng = np.random.default_rng(0)
    S = np.zeros((2, 14))
    S[:, 0] = 1.0
    S[:, 4:7] = [[0.2, 0.2, 0.0], [0.2, -0.2, 0.0]]
    S[:, 7:] = rng.normal(0, 0.3, (2, 7))
    for _ in range(500):  # warm-up
        pol.act(S)
    us = np.empty(args.ticks)
    cpu0 = time.process_time()
    for i in range(args.ticks):
        t0 = time.perf_counter()
        pol.act(S)
        us[i] = (time.perf_counter() - t0) * 1e6
    cpu_us = (time.process_time() - cpu0) / args.ticks * 1e6
    out = {
        "what": "PosturePolicy.act: encoder + decoder + gate, both arms, one tick (numpy only)",
        "ticks": args.ticks,
        "us_mean": float(us.mean()),
        "us_p50": float(np.percentile(us, 50)),
        "us_p99": float(np.percentile(us, 99)),
        "us_min": float(us.min()),
        # CPU time of this process per tick: what the inference costs, without the waits for a CPU
        # that wall-clock figures include on a loaded machine.
        "cpu_us_mean": float(cpu_us),
        "budget_us": BUDGET_US,
        "policy": str(args.policy),
    }
    text = json.dumps(out, indent=2)
    if args.json:
        Path(args.json).write_text(text)
    sys.stdout.write(text + "\n")
    return 0
