"""Joint-range centring (services/solver/centring.py): its weights, its joints, and strictness in the solver."""

from __future__ import annotations

import numpy as np

from services.solver.centring import RangeCentringTask, centred_joints
from services.solver.core import SolverConfig, SolverCore
from shared.kinematics import Configuration
from tests.solver.test_core import targets_from_q

DT = 0.002


def test_centred_joints_are_the_waist_and_the_shoulders(robot17, robot14):
    names = {robot17.joint_names[i] for i in centred_joints(robot17)}
    profile = robot17.profile
    assert names == {*profile.waist, *profile.arms["left"].shoulder, *profile.arms["right"].shoulder}
    assert not names & {profile.arms["left"].elbow, *profile.arms["left"].wrist}
    # an arms-only model centres the shoulders only
    assert {robot14.joint_names[i] for i in centred_joints(robot14)} == names - set(profile.waist)


def test_weight_is_zero_mid_range_quadratic_in_the_band_and_the_cost_at_a_stop(robot17):
    task = RangeCentringTask(robot17, cost=3.0, band=0.25, gain=5.0)
    lo, hi = robot17.lower[task.joints], robot17.upper[task.joints]
    mid = 0.5 * (lo + hi)
    q = robot17.q_rest.copy()
    q[task.joints] = mid
    task.update(q)
    assert np.all(task.cost == 0.0)
    for frac, want in ((0.0, 3.0), (0.125, 0.75), (0.25, 0.0), (0.3, 0.0)):
        q[task.joints] = lo + frac * (hi - lo)
        task.update(q)
        np.testing.assert_allclose(task.cost, want, atol=1e-9)
        q[task.joints] = hi - frac * (hi - lo)
        task.update(q)
        np.testing.assert_allclose(task.cost, want, atol=1e-9)
    # rows: the centred joints only, pulled back to the band's inner edge at the gain
    q[task.joints] = hi - 0.1 * (hi - lo)
    task.update(q)
    conf = Configuration(robot17)
    conf.update(q)
    A, b = task.compute_qp_objective(conf)
    assert np.all(A[:, np.setdiff1d(np.arange(robot17.nq), task.joints)] == 0.0)
    np.testing.assert_allclose(b, task.cost * 5.0 * (-0.15 * (hi - lo)), rtol=1e-9)
    assert np.all(b < 0)  # away from the upper stop


def test_solver_leaves_a_shoulder_stop_without_moving_the_wrists(robot17):
    # The left shoulder roll 1 % of its range from its upper stop, targets exactly where the arm is: every
    # tracking task is met, so only the centring asks for motion; level 1 (wrists) must stay met.
    robot = robot17
    j = robot.joint_names.index("left_shoulder_roll_joint")
    q0 = robot.q_rest.copy()
    q0[j] = robot.upper[j] - 0.01 * (robot.upper[j] - robot.lower[j])
    moved, wrist_err = {}, {}
    for cost in (0.0, SolverConfig().range_centring_cost):
        core = SolverCore(robot, SolverConfig(qp="daqp", range_centring_cost=cost))
        core.reset(q0)
        for k in range(500):
            cmd = core.step(targets_from_q(robot, q0, seq=k, stamp=k * DT), None, k * DT)
            assert cmd.residuals[0] < 1e-3  # level 1 untouched at every tick
        moved[cost] = q0[j] - cmd.q[j]
        poses = robot.frame_poses(cmd.q)
        want = robot.frame_poses(q0)
        wrist_err[cost] = max(np.linalg.norm(poses[w][0] - want[w][0]) for w in ("left_wrist", "right_wrist"))
    assert abs(moved[0.0]) < 1e-3, moved  # nothing else asks the joint to move
    assert moved[SolverConfig().range_centring_cost] > 0.05, moved  # out of the stop
    assert wrist_err[SolverConfig().range_centring_cost] < 1e-3, wrist_err


def test_compiled_weights_and_rows_give_the_numpy_steps_bits(robot17):
    """``RangeCentringTask(compiled=True)`` (``tick_kernel``) against the numpy steps, bit for bit: joints mid-range,
    in the band and past the stops, weights and rows."""
    fast = RangeCentringTask(robot17, cost=3.0, band=0.25, gain=20.0, compiled=True)
    ref = RangeCentringTask(robot17, cost=3.0, band=0.25, gain=20.0)
    assert fast._kernel is not None and ref._kernel is None
    conf = Configuration(robot17)
    rng = np.random.default_rng(4)
    lo, hi = robot17.lower, robot17.upper
    in_band = 0
    for _ in range(300):
        q = rng.uniform(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        conf.q[:] = q  # the rows read conf.q only (no kinematics needed)
        for task in (fast, ref):
            task.update(q)
        np.testing.assert_array_equal(fast.cost, ref.cost)
        A, b = fast.compute_qp_objective(conf)
        A_ref, b_ref = ref.compute_qp_objective(conf)
        np.testing.assert_array_equal(A, A_ref)
        np.testing.assert_array_equal(b, b_ref)
        in_band += int(np.count_nonzero((ref.cost > 0) & (ref.cost < 3.0)))
    assert in_band > 300  # the weights were compared inside the band, not only at 0
