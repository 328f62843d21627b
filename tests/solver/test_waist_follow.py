"""The waist pulled towards the operator's torso on level 2 (``SolverConfig.waist_follow_cost``): it follows
``TaskTargets.waist`` where the hands allow it, holds the last one through frames without it, and never at the
wrists' expense."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import SolverConfig, SolverCore
from shared.messages import Header, Target, TaskTargets
from shared.rotations import matrix_to_quat
from shared.targets import TARGET_NAMES
from tests.support.lockstep import step_through

#: The operator's torso: yawed 0.3 rad, rolled 0.05, pitched 0.1 (waist yaw, roll, pitch [rad]).
TORSO = np.array([0.3, 0.05, 0.1])


def _posed(robot, waist: np.ndarray) -> np.ndarray:
    """The rest pose (n,) with the waist at ``waist`` (3,) [rad]."""
    q = robot.q_rest.copy()
    q[[robot.joint_names.index(j) for j in robot.profile.waist]] = waist
    return q


def _frames(robot, q: np.ndarray, seconds: float, waist: np.ndarray | None) -> list[TaskTargets]:
    """30 fps frames holding every target where the posture q puts it (wrist orientations tracked), each carrying
    ``waist`` (None: no waist, as a source without a measured chest)."""
    poses = robot.frame_poses(q)
    tg = {n: Target(poses[n][0], matrix_to_quat(poses[n][1]), np.zeros(3), np.zeros(3), True, n.endswith("wrist"))
          for n in TARGET_NAMES}  # fmt: skip
    w = np.zeros(0) if waist is None else waist
    return [TaskTargets(Header(k, k / 30.0, 0), tg, waist=w) for k in range(int(seconds * 30))]


def _waist(core: SolverCore, robot) -> np.ndarray:
    return core.configuration.q[[robot.joint_names.index(j) for j in robot.profile.waist]]


@pytest.mark.parametrize("cost", [0.3, 1.0])
def test_the_waist_follows_the_operator_torso_with_the_hands_on_their_targets(robot17, cost):
    """Targets where the robot, its torso turned like the operator's, puts its hands and elbows: from the rest pose
    the waist goes to the operator's angles within 0.01 rad and the wrists stay on their targets; without the pull
    (the default) the waist ends elsewhere, the hands reached with the arms."""
    q_op = _posed(robot17, TORSO)
    frames = _frames(robot17, q_op, 4.0, TORSO)
    core = SolverCore(robot17, SolverConfig(waist_follow_cost=cost))
    core.reset(robot17.q_rest)
    step_through(core, frames)
    np.testing.assert_allclose(_waist(core, robot17), TORSO, atol=0.01)
    poses = robot17.frame_poses(core.configuration.q)
    for n in ("left_wrist", "right_wrist"):
        assert np.linalg.norm(poses[n][0] - frames[-1].targets[n].p) < 1e-3
    off = SolverCore(robot17, SolverConfig())
    assert off.waist_task is None
    off.reset(robot17.q_rest)
    step_through(off, frames)
    assert np.abs(_waist(off, robot17) - TORSO).max() > 0.05


def test_frames_without_a_waist_hold_the_last_one(robot17):
    """After 2 s of frames with the operator's torso, 2 s without a waist (the chest lost): the waist stays there
    rather than falling back to the rest pose."""
    q_op = _posed(robot17, TORSO)
    frames = _frames(robot17, q_op, 2.0, TORSO)
    later = _frames(robot17, q_op, 2.0, None)
    for k, f in enumerate(later):
        f.hdr = Header(len(frames) + k, (len(frames) + k) / 30.0, 0)
    core = SolverCore(robot17, SolverConfig(waist_follow_cost=0.3))
    core.reset(robot17.q_rest)
    step_through(core, frames + later)
    np.testing.assert_allclose(_waist(core, robot17), TORSO, atol=0.01)
