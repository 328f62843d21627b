"""Recorded targets from a real clip, and a SolverCore driven through them in lock-step (no bus, no wall clock)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from services.evaluation.runner import clip_targets, load_and_retarget
from services.ingest import load_clip
from services.retarget.elbow import ArmGeometry
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.retarget.workspace import Workspace, sample_workspace
from services.solver.core import SolverCore
from shared.messages import TaskTargets
from shared.paths import mocap_dir
from shared.robot.pinocchio_model import build_robot_model
from shared.targets import SIDES


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


def clip_targets_until(
    name: str, robot, until: float, retarget: dict | None = None, per_arm_draws: bool = False
) -> list[TaskTargets]:
    """The eval's retargeted targets of ``bvh/<name>`` for ``robot``, the first ``until`` [s] of the clip (``retarget``:
    RetargetConfig fields other than the service's); skips the test when the clip is not in the data folder.

    ``per_arm_draws``: retarget as before session 21, each arm's workspace cloud and shoulder-centre fit its own Monte
    Carlo draw (about 2 mm off each other's mirror image), for the tests that replay a failure recorded on those
    targets (a lock is a branch of the path: the 2 mm move the kick's lock from rest out of reach)."""
    path = mocap_dir() / "bvh" / name
    if not path.exists():
        pytest.skip(f"clip {path} not in the data folder")
    if not per_arm_draws:
        _clip, targets = load_and_retarget(path, robot, retarget=retarget)
    else:
        arms = build_robot_model(robot.profile, with_waist=False)
        cfg = RetargetConfig(robot=str(robot.profile.source), **(retarget or {}))
        points = sample_workspace(arms, cfg.samples, cfg.seed, progress=False)  # not pooled
        retargeter = Retargeter(cfg, workspace=Workspace(points, shrink=cfg.shrink), robot=arms)
        retargeter.arms = {s: ArmGeometry.measure(arms, s) for s in SIDES}  # each side its own fit
        targets = clip_targets(load_clip(path), retargeter)
    return [t for t in targets if t.hdr.stamp <= until]
