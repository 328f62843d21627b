"""Seed 003's Newton-Raphson IK and its damped variants converge where a Pinocchio-based IK does."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from shared.kinematics.ik import ik_space
from shared.kinematics.poe import fk_space
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.wheeled import arm_screws


def pinocchio_ik(model, data, fid, oMdes, q0, iters=300, damp=1e-12, dt=0.5, eps=1e-6):
    """Pinocchio's documented CLIK loop (log6 error, Jlog6, damped pseudo-inverse, step dt)."""
    q = q0.copy()
    for i in range(iters):
        pin.framesForwardKinematics(model, data, q)
        iMd = data.oMf[fid].actInv(oMdes)
        err = pin.log(iMd).vector
        if np.linalg.norm(err) < eps:
            return q, True, i
        J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
        J = -pin.Jlog6(iMd.inverse()) @ J
        v = -J.T @ np.linalg.solve(J @ J.T + damp * np.eye(6), err)
        q = pin.integrate(model, q, v * dt)
    return q, False, iters


@pytest.fixture(scope="module")
def arm():
    robot = build_robot_model(with_waist=False)
    joints = robot.profile.arms["right"].joints
    frame = robot.profile.orientation_frame("right_wrist")  # the hand link, a rigid frame at the chain's end
    S, M = arm_screws(robot.model, joints, frame, robot.profile.base_frame)
    idx = [robot.model.joints[robot.model.getJointId(j)].idx_q for j in joints]
    return robot, S, M, idx, robot.model.getFrameId(frame)


@pytest.mark.parametrize(
    ("method", "kwargs", "pin_kwargs"),
    [
        # Like against like: a full Newton step, a shortened step, a damped least-squares step.
        ("newton", {}, {"dt": 1.0}),
        ("damped", {"step": 0.5}, {"dt": 0.5}),
        ("dls", {"lamb": 1e-3}, {"dt": 1.0, "damp": 1e-3}),
    ],
)
def test_ik_converges_where_pinocchio_does(arm, method, kwargs, pin_kwargs):
    robot, S, M, idx, fid = arm
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(21)
    both = pin_only = 0
    for q_goal in robot.random_configurations(30, rng):
        T_goal = fk_space(M, S, q_goal[idx])
        q0 = robot.q_rest.copy()
        q0[idx] = q_goal[idx] + rng.normal(scale=0.3, size=len(idx))
        _, pin_ok, _ = pinocchio_ik(
            model, data, fid, pin.SE3(T_goal[:3, :3], T_goal[:3, 3]), q0, iters=100, **pin_kwargs
        )
        res = ik_space(S, M, T_goal, q0[idx], method=method, max_iterations=300, **kwargs)
        if pin_ok:
            if res.success:
                both += 1
                # The solution reaches the goal in Pinocchio's own FK too.
                q = q0.copy()
                q[idx] = res.theta
                pin.framesForwardKinematics(model, data, q)
                assert np.abs(data.oMf[fid].homogeneous - T_goal).max() < 1e-5
            else:
                pin_only += 1
    assert both >= 25, f"{method}: converged on {both} of the goals Pinocchio solved"
    assert pin_only == 0, f"{method}: failed on {pin_only} goals Pinocchio solved"


def test_newton_converges_within_a_few_iterations(arm):
    """Seed 003: 'usually within 5 iterations' from a start near the solution."""
    robot, S, M, idx, _ = arm
    rng = np.random.default_rng(4)
    iters = []
    for q_goal in robot.random_configurations(20, rng):
        T_goal = fk_space(M, S, q_goal[idx])
        res = ik_space(S, M, T_goal, q_goal[idx] + rng.normal(scale=0.05, size=len(idx)))
        assert res.success
        iters.append(res.iterations)
    # "Generally within 5 iterations" (seed 003) at a 1e-6 tolerance.
    assert np.median(iters) <= 4
    assert np.mean(np.array(iters) <= 5) >= 0.9


def test_ik_rejects_unknown_method(arm):
    _, S, M, idx, _ = arm
    with pytest.raises(ValueError, match="unknown IK method"):
        ik_space(S, M, np.eye(4), np.zeros(len(idx)), method="bfgs")
