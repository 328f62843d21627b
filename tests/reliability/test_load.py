"""Load (issue 8, item 5): a 10 kHz burst of HumanFrames into the real stack.

Frames are published from the test process at 10 kHz for a few seconds (the
10-second figure: ``python -m tests.support.faults burst --rate 10000 --duration 10``).
The frames come from a process of their own (a 10 kHz publisher in the observer's
process would hold its GIL and stamp arrivals late). Newest wins: each service
takes samples from a Rust-side ring (no GIL per sample, so nothing backs up in
Zenoh or the kernel), retarget keeps a queue whose stale frames it skips and the
solver and sim keep the newest message, so the end-to-end latency stays bounded
and does not grow from the first to the last second; frames skipped in the ring
show up as gaps in the publisher's numbering and those skipped in the mailboxes
as dropped.
"""

from __future__ import annotations

import json

import pytest

from tests.support.faults import PIPELINE, burst, running_stack

pytestmark = [pytest.mark.integration, pytest.mark.slow]
RATE = 10000.0
DURATION = 5.0
#: The burst saturates both cores (the publisher alone takes ~1), so single windows spike with CPU
#: scheduling: one-second p99s of 215-1560 ms in quiet runs of this code. The bound only rules out the
#: absurd; the trend check below is what tells bounded from queueing.
P99_BOUND_MS = 2500.0
#: The last second's p50 [ms]: far below where queueing would have taken it by then (see the check).
LAST_P50_BOUND_MS = 1000.0


def test_10khz_burst_latency_stays_bounded_and_drops_are_counted():
    with running_stack(clip_loop=False) as (stack, obs):
        r = burst(stack, obs, RATE, DURATION)
    ctx = json.dumps({k: v for k, v in r.items() if k != "windows"}, indent=1, default=float)
    assert all(r["alive"][n] for n in PIPELINE), ctx
    # The publisher really produced a burst far above what the pipeline can take.
    assert r["achieved_rate_hz"] > 3000, ctx
    assert r["reached"] > 10, ctx
    first, last = r["first_s"], r["last_s"]
    assert first is not None and last is not None and last["t_s"] >= DURATION - 2.0, ctx
    # Bounded, and not trending up: every second under the absurd bound, the last one far below where
    # queueing would have taken it.
    assert max(w["p99"] for w in r["windows"] if "p99" in w) < P99_BOUND_MS, ctx
    # Queueing shows as growth: the old callback path went from p50 245 ms in the first second to 965 ms
    # in the fourth (~240 ms more each second), so by the last second of this burst it would be past
    # 1.4 s. Bounded, the last second's p50 was 55-590 ms in 11 runs here, with plateaus near 500 (first seconds 22-411
    # ms: a bound relative to the first second failed CI once at 112 -> 586 ms, a noisy 14-frame window).
    assert last["p50"] < LAST_P50_BOUND_MS, ctx
    # Old frames are dropped and counted, at retarget (bounded queue) and downstream.
    d = r["dropped"]
    assert d["retarget/main"].get("dropped.frames", 0) > 0, ctx
    # Nothing vanishes silently inside retarget: every frame it received was retargeted, rejected or
    # counted as dropped (the queue is drained by the time of the last status).
    c = r["retarget_counts"]
    unaccounted = c["received.frames"] - c.get("published.targets", 0) - c.get("dropped.frames", 0)
    unaccounted -= c.get("rejected", 0)
    assert 0 <= unaccounted <= 32, (unaccounted, c)
    assert d["solver/main"].get("dropped.targets", 0) + d["sim/main"].get("dropped.commands", 0) > 0, ctx
