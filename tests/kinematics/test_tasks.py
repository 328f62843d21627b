"""Task errors and Jacobians on the real G1 model, checked against finite differences."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from shared.kinematics import (
    Configuration,
    FrameTask,
    InvalidConfigurationError,
    InvalidFrameError,
    InvalidTargetError,
    PositionTask,
    PostureTask,
)
from shared.robot.pinocchio_model import build_robot_model

H = 1e-6


@pytest.fixture(scope="module", params=[True, False], ids=["17dof", "14dof"])
def robot(request):
    return build_robot_model(with_waist=request.param)


def _fd_frame_jacobian(robot, q: np.ndarray, frame: str) -> np.ndarray:
    """Central differences of the frame's position and of its rotation increment in the base frame."""
    conf = Configuration(robot, q)
    n = robot.nq
    J = np.zeros((6, n))
    for i in range(n):
        dq = np.zeros(n)
        dq[i] = H
        conf.update(q + dq)
        p_plus, R_plus = (x.copy() for x in conf.get_frame_pose(frame))
        conf.update(q - dq)
        p_minus, R_minus = (x.copy() for x in conf.get_frame_pose(frame))
        J[:3, i] = (p_plus - p_minus) / (2 * H)
        J[3:, i] = pin.log3(R_plus @ R_minus.T) / (2 * H)
    return J


@pytest.mark.parametrize("frame", ["left_wrist", "right_wrist", "left_elbow", "right_elbow"])
def test_frame_task_jacobian_matches_finite_differences(robot, frame):
    rng = np.random.default_rng(1)
    for q in robot.random_configurations(3, rng):
        conf = Configuration(robot, q)
        task = FrameTask(frame)
        J = task.compute_jacobian(conf).copy()
        assert J.shape == (6, robot.nq)
        np.testing.assert_allclose(J, _fd_frame_jacobian(robot, q, frame), atol=1e-7)


@pytest.mark.parametrize("frame", ["left_elbow", "right_elbow", "left_wrist"])
def test_position_task_jacobian_matches_finite_differences(robot, frame):
    rng = np.random.default_rng(2)
    q = robot.random_configurations(1, rng)[0]
    task = PositionTask(frame)
    J = task.compute_jacobian(Configuration(robot, q)).copy()
    np.testing.assert_allclose(J, _fd_frame_jacobian(robot, q, frame)[:3], atol=1e-7)


def test_errors_are_minus_the_derivative_near_the_target(robot):
    """d e / d q = -J for every task: the error's own finite differences, next to its target."""
    rng = np.random.default_rng(3)
    q = robot.random_configurations(1, rng)[0]
    conf = Configuration(robot, q)
    frame = FrameTask("left_wrist")
    frame.set_target_from_configuration(conf)
    pos = PositionTask("right_elbow")
    pos.set_target_from_configuration(conf)
    posture = PostureTask(q)
    for task in (frame, pos, posture):
        J = task.compute_jacobian(conf).copy()
        fd = np.zeros_like(J)
        for i in range(robot.nq):
            dq = np.zeros(robot.nq)
            dq[i] = H
            conf.update(q + dq)
            e_plus = task.compute_error(conf).copy()
            conf.update(q - dq)
            e_minus = task.compute_error(conf).copy()
            fd[:, i] = (e_plus - e_minus) / (2 * H)
        conf.update(q)
        np.testing.assert_allclose(fd, -J, atol=1e-6)


def test_frame_error_is_target_minus_current(robot):
    rng = np.random.default_rng(4)
    qa, qb = robot.random_configurations(2, rng)
    conf = Configuration(robot, qa)
    pb = robot.frame_poses(qb)["left_wrist"]
    task = FrameTask("left_wrist")
    task.set_target(*pb)
    e = task.compute_error(conf)
    pa, Ra = conf.get_frame_pose("left_wrist")
    np.testing.assert_allclose(e[:3], pb[0] - pa, atol=1e-12)
    # Rotating the current orientation by the error's rotation vector (base frame) reaches the target.
    np.testing.assert_allclose(pin.exp3(e[3:]) @ Ra, pb[1], atol=1e-9)


def test_qp_objective_is_weighted_feedforward_plus_gain_times_error(robot):
    conf = Configuration(robot)
    task = FrameTask("right_wrist", position_cost=2.0, orientation_cost=0.5, gain=10.0)
    p, R = (x.copy() for x in conf.get_frame_pose("right_wrist"))
    v, w = np.array([0.1, 0.0, -0.2]), np.array([0.0, 0.3, 0.0])
    task.set_target(p + 0.01, R, v, w)
    A, b = task.compute_qp_objective(conf)
    W = np.array([2.0] * 3 + [0.5] * 3)
    np.testing.assert_allclose(A, W[:, None] * conf.get_frame_jacobian("right_wrist"))
    np.testing.assert_allclose(b, W * (np.r_[v, w] + 10.0 * task.compute_error(conf)))


def test_bad_inputs_raise_clear_errors(robot):
    conf = Configuration(robot)
    with pytest.raises(InvalidFrameError, match="left_wrist"):
        FrameTask("no_such_frame").compute_error(conf)
    with pytest.raises(InvalidTargetError):
        FrameTask("left_wrist").set_target(np.array([np.nan, 0, 0]), np.eye(3))
    with pytest.raises(InvalidTargetError):
        PositionTask("left_elbow").set_target(np.zeros(2))
    with pytest.raises(InvalidConfigurationError):
        conf.update(np.zeros(robot.nq + 1))
    with pytest.raises(ValueError, match="gain"):
        PositionTask("left_elbow", gain=-1.0)


def test_frame_reads_follow_every_update(robot):
    """Poses and Jacobians are read once per update and shared: each update must replace them with the new q's."""
    conf = Configuration(robot)
    rng = np.random.default_rng(3)
    data = robot.model.createData()
    fid, rid = robot.frame_id("left_wrist"), robot.rotation_id("left_wrist")  # the G1's wrist: two frames
    for q in robot.random_configurations(5, rng):
        conf.update(q)
        p, R = conf.get_frame_pose("left_wrist")
        J = conf.get_frame_jacobian("left_wrist")
        assert conf.get_frame_pose("left_wrist")[0] is p and conf.get_frame_jacobian("left_wrist") is J  # one read
        pin.computeJointJacobians(robot.model, data, q)
        pin.updateFramePlacements(robot.model, data)
        np.testing.assert_array_equal(p, data.oMf[fid].translation)
        np.testing.assert_array_equal(R, data.oMf[rid].rotation)
        np.testing.assert_array_equal(J[:3], pin.getFrameJacobian(robot.model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3])
        np.testing.assert_array_equal(J[3:], pin.getFrameJacobian(robot.model, data, rid, pin.LOCAL_WORLD_ALIGNED)[3:])


def test_specialised_rows_equal_the_generic_ones(robot):
    """Position, pose and posture tasks fill their rows with fewer calls: the same bits as A = W J, b = W (v + k e)."""
    rng = np.random.default_rng(4)
    conf = Configuration(robot, robot.random_configurations(1, rng)[0])
    p, R = (x.copy() for x in conf.get_frame_pose("right_wrist"))
    tasks = [PositionTask("left_elbow", 0.7, 30.0), FrameTask("right_wrist", 2.0, 0.5, 10.0)]
    tasks[0].set_target(conf.get_frame_pose("left_elbow")[0] + 0.02, rng.normal(size=3))
    tasks[1].set_target(p - 0.01, pin.exp3(rng.normal(size=3) * 0.2) @ R, rng.normal(size=3), rng.normal(size=3))
    posture = PostureTask(robot.q_rest, 1e-2, 5.0)
    for task in (*tasks, posture):
        A, b = np.empty((task.dim, robot.nq)), np.empty(task.dim)
        task.fill_qp_objective(conf, A, b)
        W = task.cost
        np.testing.assert_array_equal(A, W[:, None] * task.compute_jacobian(conf))
        np.testing.assert_array_equal(b, W * (task.feedforward() + task.gain * task.compute_error(conf)))
        assert np.abs(b).max() > 0
