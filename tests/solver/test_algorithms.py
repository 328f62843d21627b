"""Every algorithm honours one contract; CLIK's null-space property; DLS and the paper's hierarchy track."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from test_core import DT, moving_targets

from services.solver.base import level_residuals
from services.solver.clik_nullspace import ClikNullspace
from services.solver.core import SolverConfig, SolverCore
from services.solver.registry import ALGORITHMS, make_algorithm
from shared.kinematics import Configuration
from shared.robot.pinocchio_model import build_robot_model


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def smooth_motion(robot, seed: int):
    rng = np.random.default_rng(seed)
    amp = 0.35 * rng.uniform(-1, 1, robot.nq)
    freq = rng.uniform(0.5, 1.5, robot.nq)

    def q_of_t(t):
        return robot.clip(robot.q_rest + amp * np.sin(freq * t))

    return q_of_t


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_every_algorithm_solves_matrices_and_reports_its_true_residuals(robot, name):
    """The contract: solve_matrices on random stacks, a qd inside the box, residuals of that qd."""
    alg = make_algorithm(name, "daqp", (1e-6, 1e-5))
    rng = np.random.default_rng(3)
    n = robot.nq
    for _ in range(20):
        As = [rng.standard_normal((6, n)), rng.standard_normal((6, n)), 0.1 * np.eye(n)]
        bs = [rng.standard_normal(6), rng.standard_normal(6), rng.standard_normal(n)]
        lb, ub = -rng.uniform(0.1, 1.0, n), rng.uniform(0.1, 1.0, n)
        sol = alg.solve_matrices(As, bs, lb, ub)
        assert sol.ok, sol.reason
        assert np.all(sol.qd >= lb - 1e-12) and np.all(sol.qd <= ub + 1e-12)
        np.testing.assert_allclose(sol.residuals, level_residuals(As, bs, sol.qd), rtol=1e-12, atol=1e-12)


def test_clik_null_space_term_never_moves_the_wrists(robot):
    """On the real wrist Jacobians: the secondary term changes qd a lot but the wrist velocity not at all."""
    core = SolverCore(robot, SolverConfig(algo="clik-nullspace"))
    conf = Configuration(robot)
    rng = np.random.default_rng(9)
    wide = np.full(robot.nq, 1e6)
    moved = 0
    for q in robot.random_configurations(30, rng):
        conf.update(q)
        for task, target in zip(core.wrist_tasks + core.elbow_tasks, rng.standard_normal((4, 3)) * 0.1):
            p, R = conf.get_frame_pose(task.frame)
            if hasattr(task, "R_target"):
                task.set_target(p + target, R)
            else:
                task.set_target(p + target)
        As, bs = core.algorithm.stack(core.levels, robot.nq).fill(conf)
        with_term = ClikNullspace(eta=1.0).solve_matrices(As, bs, -wide, wide).qd
        without = ClikNullspace(eta=0.0).solve_matrices(As, bs, -wide, wide).qd
        step = with_term - without
        J = np.vstack([conf.get_frame_jacobian(w) for w in ("left_wrist", "right_wrist")])[[0, 1, 2, 6, 7, 8]]
        assert np.linalg.norm(J @ step) <= 1e-9 * (1.0 + np.linalg.norm(step))
        moved += np.linalg.norm(step) > 1e-3
    assert moved > 25  # the secondary objective did act


def track(robot, cfg: SolverConfig, seconds: float = 1.5, seed: int = 2):
    """Run SolverCore on exactly reachable moving targets (FK of a smooth motion, 100 Hz frames)."""
    core = SolverCore(robot, cfg)
    q_of_t = smooth_motion(robot, seed)
    core.reset(q_of_t(0.0))
    pos_err, rot_err, statuses = [], [], []
    for k in range(int(seconds / DT)):
        t = k * DT
        cmd = core.step(moving_targets(robot, q_of_t, t, k) if k % 5 == 0 else None, None, t)
        if t < 0.2:
            continue  # the smoother's start-up transient
        statuses.append(cmd.status)
        got, want = robot.frame_poses(cmd.q), robot.frame_poses(q_of_t(t + DT))
        for w in ("left_wrist", "right_wrist"):
            pos_err.append(np.linalg.norm(got[w][0] - want[w][0]))
            rot_err.append(np.linalg.norm(pin.log3(got[w][1].T @ want[w][1])))
    return np.array(pos_err), np.array(rot_err), statuses


def test_dls_tracks_reachable_targets_and_reports_ok(robot):
    """DLS with the configured gain: wrists within 0.03 mm and status ok (not infeasible) on reachable targets
    (measured: mean 0.005 mm, max 0.011 mm; the old position-level DLS said infeasible on 19 % of ticks)."""
    pos, _rot, statuses = track(robot, SolverConfig(algo="dls"))
    assert np.mean(pos) < 2e-5 and np.max(pos) < 3e-5, (np.mean(pos), np.max(pos))
    assert statuses.count("ok") / len(statuses) > 0.99, {s: statuses.count(s) for s in set(statuses)}


def test_paper_hierarchy_puts_full_wrist_poses_on_level_one(robot):
    """--wrist-orientation-level 1: the wrist poses (position and orientation) are level 1 and are tracked."""
    cfg = SolverConfig(qp="daqp", wrist_orientation_level=1)
    core = SolverCore(robot, cfg)
    assert [t.frame for t in core.levels[0]] == ["left_wrist", "right_wrist"]
    assert all(np.all(t.cost[3:] > 0) for t in core.levels[0]) and not core.orientation_tasks
    pos, rot, statuses = track(robot, cfg)
    # Measured: 0.011 mm and 0.003 deg at most.
    assert np.max(pos) < 3e-5 and np.max(rot) < np.radians(0.01), (np.max(pos), np.degrees(np.max(rot)))
    assert statuses.count("ok") / len(statuses) > 0.99
    # The default (orientations on level 2 with the elbows) meets the same reachable poses too, but
    # only as closely as its lower-level damping and gain allow: level 1 is the tighter one.
    _pos2, rot2, _ = track(robot, SolverConfig(qp="daqp"))
    assert np.mean(rot) < np.mean(rot2)
