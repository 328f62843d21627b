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
#: Width of the reference layer timed beside the policy.
REF_WIDTH = 128


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
    # Same-run references, timed in the same loop as the policy (tick by tick, interleaved), so a reader
    # can tell a slow VM from slow code: a no-op Python call, and one dense float32 layer the size of the
    # policy's hidden layers (x (1, 128) @ W (128, 128), tanh) on fixed data.
    x = rng.normal(size=(1, REF_WIDTH)).astype(np.float32)
    W = (rng.normal(size=(REF_WIDTH, REF_WIDTH)) / np.sqrt(REF_WIDTH)).astype(np.float32)
    y = np.empty((1, REF_WIDTH), np.float32)

    def layer() -> None:
        np.tanh(np.matmul(x, W, out=y), out=y)

    def noop() -> None:
        return None

    for _ in range(500):  # warm-up
        pol.act(S)
        layer()
    us = np.empty(args.ticks)
    ref = np.empty((2, args.ticks))
    clock = time.perf_counter
    cpu_act = 0.0
    for i in range(args.ticks):
        c0 = time.process_time()
        t0 = clock()
        pol.act(S)
        t1 = clock()
        cpu_act += time.process_time() - c0
        layer()
        t2 = clock()
        noop()
        t3 = clock()
        us[i], ref[0, i], ref[1, i] = t1 - t0, t2 - t1, t3 - t2
    us *= 1e6
    ref *= 1e6
    p50 = float(np.percentile(us, 50))
    layer_p50 = float(np.percentile(ref[0], 50))
    out = {
        "what": "PosturePolicy.act: encoder + decoder + gate, both arms, one tick (numpy only)",
        "ticks": args.ticks,
        "us_mean": float(us.mean()),
        "us_p50": p50,
        "us_p99": float(np.percentile(us, 99)),
        "us_min": float(us.min()),
        # CPU time of this process per tick: what the inference costs, without the waits for a CPU
        # that wall-clock figures include on a loaded machine.
        "cpu_us_mean": float(cpu_act / args.ticks * 1e6),
        "budget_us": BUDGET_US,
        "reference": {
            "what": f"same loop, after each tick: one float32 layer tanh(x (1, {REF_WIDTH}) @ W ({REF_WIDTH}, "
            f"{REF_WIDTH})) and a no-op Python call",
            "layer_us_p50": layer_p50,
            "layer_us_min": float(ref[0].min()),
            "noop_us_p50": float(np.percentile(ref[1], 50)),
            # the VM's speed cancels in this ratio: compare it across runs and machines
            "p50_in_layers": p50 / layer_p50,
        },
        "policy": str(args.policy),
        "network": pol.meta.get("network"),
    }
    text = json.dumps(out, indent=2)
    if args.json:
        Path(args.json).write_text(text)
    sys.stdout.write(text + "\n")
    return 0
