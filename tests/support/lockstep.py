"""Recorded targets from a real clip, and a SolverCore driven through them in lock-step (no bus, no wall clock)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from services.evaluation.runner import load_and_retarget
from services.solver.core import SolverCore
from shared.messages import TaskTargets
from shared.paths import mocap_dir


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


def clip_targets_until(name: str, robot, until: float, retarget: dict | None = None) -> list[TaskTargets]:
    """The eval's retargeted targets of ``bvh/<name>`` for ``robot``, the first ``until`` [s] of the clip (``retarget``:
    RetargetConfig fields other than the service's); skips the test when the clip is not in the data folder."""
    path = mocap_dir() / "bvh" / name
    if not path.exists():
        pytest.skip(f"clip {path} not in the data folder")
    _clip, targets = load_and_retarget(path, robot, retarget=retarget)
    return [t for t in targets if t.hdr.stamp <= until]
