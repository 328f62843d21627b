"""Drive a SolverCore through recorded targets in lock-step (no bus, no wall clock)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from services.solver.core import SolverCore
from shared.messages import TaskTargets


def step_through(core: SolverCore, frames: Sequence[TaskTargets]) -> int:
    """Tick ``core`` at its configured rate over the frames' span, each frame handed over at the first tick at or
    after its own stamp (relative to the first frame's) [s]. Returns the number of ticks."""
    stamps = np.array([f.hdr.stamp for f in frames]) - frames[0].hdr.stamp
    ticks = int(stamps[-1] * core.config.rate) + 1
    j = 0
    for k in range(ticks):
        t = k / core.config.rate
        msg = None
        while j < len(frames) and stamps[j] <= t + 1e-9:
            msg, j = frames[j], j + 1
        core.step(msg, None, t)
    return ticks
