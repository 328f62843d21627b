"""The batched frame-task rows (``FrameRows``) against every task's own ``fill_qp_objective``, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import SolverConfig, SolverCore
from services.solver.frame_rows import batchable
from services.solver.levels import LevelStack
from shared.kinematics import Configuration
from shared.robot.pinocchio_model import build_robot_model


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def _aim_everywhere(core: SolverCore, conf: Configuration, rng: np.random.Generator) -> None:
    """Random targets, feed-forwards, gains and orientation costs on every frame task (none equal)."""
    for task in {id(t): t for lv in core._levels_elbow_poses for t in lv}.values():
        if not batchable(task):
            continue
        p, R = conf.get_frame_pose(task.frame)
        v = rng.standard_normal(3)
        if task.dim == 6:
            w = rng.standard_normal(3)
            R_t = R @ np.linalg.qr(np.eye(3) + 0.3 * rng.standard_normal((3, 3)))[0]
            task.set_target(p + 0.1 * rng.standard_normal(3), R_t * np.sign(np.linalg.det(R_t)), v, w)
            task.set_orientation_cost(rng.uniform(0.1, 1.0))
        else:
            task.set_target(p + 0.1 * rng.standard_normal(3), v)
        task.gain = rng.uniform(1.0, 200.0)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("orientation_level", [1, 2, 3])
def test_batched_rows_equal_each_tasks_own_rows(robot, orientation_level, compiled):
    """Every level layout the solver builds (wrist poses on 1, 2 or 3; elbow poses on): the stack's rows are
    exactly those of the per-task path, at random configurations and targets, with the arithmetic compiled
    (``tick_kernel.frame_rows``) and in numpy."""
    core = SolverCore(robot, SolverConfig(wrist_orientation_level=orientation_level))
    conf = Configuration(robot)
    rng = np.random.default_rng(orientation_level)
    for levels in (core._levels_position_elbows, core._levels_elbow_poses):
        stack = LevelStack(levels, robot.nq, compiled)
        assert (stack.frame_rows._kernel is not None) == compiled
        # Every wrist and elbow task goes through the batch (none is left to the per-task path).
        assert len(stack.frame_rows.tasks) == sum(batchable(t) for lv in levels for t in lv) >= 4
        for q in robot.random_configurations(10, rng):
            conf.update(q)
            core.centring_task.update(q)
            _aim_everywhere(core, conf, rng)
            As, bs = stack.fill(conf)
            for k, tasks in enumerate(levels):
                i = 0
                for task in tasks:
                    A_ref, b_ref = task.compute_qp_objective(conf)
                    np.testing.assert_array_equal(As[k][i : i + task.dim], A_ref, err_msg=task.name)
                    np.testing.assert_array_equal(bs[k][i : i + task.dim], b_ref, err_msg=task.name)
                    i += task.dim
