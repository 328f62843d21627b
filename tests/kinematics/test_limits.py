"""Joint limits as velocity bounds."""

from __future__ import annotations

import numpy as np
import pytest

from shared.kinematics import Configuration, ConfigurationLimit, VelocityLimit, velocity_bounds
from shared.robot.pinocchio_model import build_robot_model


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def test_one_step_with_the_bounds_never_leaves_the_limits(robot):
    rng = np.random.default_rng(0)
    dt = 0.002
    limits = [ConfigurationLimit(robot.lower, robot.upper), VelocityLimit(robot.vmax)]
    for q in robot.random_configurations(200, rng):
        conf = Configuration(robot, q)
        lb, ub = velocity_bounds(limits, conf, dt)
        assert np.all(lb <= ub)
        assert np.all(lb >= -robot.vmax) and np.all(ub <= robot.vmax)
        for qd in (lb, ub, rng.uniform(lb, ub)):
            q_next = q + qd * dt
            assert np.all(q_next >= robot.lower - 1e-12) and np.all(q_next <= robot.upper + 1e-12)


def test_near_a_limit_the_position_bound_is_the_tighter_one(robot):
    q = robot.q_rest.copy()
    q[5] = robot.upper[5] - 1e-4
    conf = Configuration(robot, q)
    lb, ub = velocity_bounds([ConfigurationLimit(robot.lower, robot.upper), VelocityLimit(robot.vmax)], conf, 0.002)
    assert ub[5] == pytest.approx(1e-4 / 0.002)
    assert lb[5] == pytest.approx(-robot.vmax[5])


def test_outside_the_limits_the_joint_returns_at_vmax(robot):
    q = robot.q_rest.copy()
    q[4] = robot.lower[4] - 0.5
    q[6] = robot.upper[6] + 0.5
    conf = Configuration(robot, q)
    lb, ub = velocity_bounds([ConfigurationLimit(robot.lower, robot.upper), VelocityLimit(robot.vmax)], conf, 0.002)
    assert lb[4] == ub[4] == pytest.approx(robot.vmax[4])
    assert lb[6] == ub[6] == pytest.approx(-robot.vmax[6])


def test_inequality_form_matches_the_box(robot):
    conf = Configuration(robot)
    limit = ConfigurationLimit(robot.lower, robot.upper)
    G, h = limit.compute_qp_inequalities(conf, 0.01)
    lb, ub = limit.compute_velocity_bounds(conf, 0.01)
    x = (lb + ub) / 2
    assert np.all(G @ x <= h)
    assert np.any(G @ (ub + 0.1) > h)
    assert np.any(G @ (lb - 0.1) > h)


def test_bad_limits_are_rejected(robot):
    with pytest.raises(ValueError):
        ConfigurationLimit(robot.upper, robot.lower)
    with pytest.raises(ValueError):
        VelocityLimit(np.zeros(3))
    with pytest.raises(ValueError, match="dt"):
        velocity_bounds([VelocityLimit(robot.vmax)], Configuration(robot), 0.0)
