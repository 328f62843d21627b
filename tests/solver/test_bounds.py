"""The solver's joint box (services/solver/bounds.py) on the real G1 limits."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.bounds import JointBounds
from shared.robot.pinocchio_model import build_robot_model

DT = 0.002  # one 500 Hz solver step [s]


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


@pytest.fixture(scope="module")
def bounds(robot):
    return JointBounds(robot.lower, robot.upper, robot.vmax, robot.amax)


def test_one_step_with_the_bounds_never_leaves_the_limits(robot, bounds):
    rng = np.random.default_rng(0)
    for q in robot.random_configurations(200, rng):
        qd_prev = rng.uniform(-0.5, 0.5, q.shape) * robot.vmax
        lb, ub = (b.copy() for b in bounds.compute(q, qd_prev, DT))
        assert np.all(lb <= ub)
        assert np.all(lb >= -robot.vmax) and np.all(ub <= robot.vmax)
        for qd in (lb, ub, rng.uniform(lb, ub)):
            q_next = q + qd * DT
            assert np.all(q_next >= robot.lower - 1e-12) and np.all(q_next <= robot.upper + 1e-12)


def test_far_from_the_limits_the_acceleration_bound_holds(robot, bounds):
    q = 0.5 * (robot.lower + robot.upper)
    qd_prev = 0.1 * robot.vmax
    lb, ub = bounds.compute(q, qd_prev, DT)
    np.testing.assert_allclose(lb, qd_prev - robot.amax * DT)
    np.testing.assert_allclose(ub, qd_prev + robot.amax * DT)


def test_near_a_limit_the_braking_bound_is_the_tighter_one(robot):
    # Acceleration and velocity limits too wide to bind: only the position (braking) term is left.
    wide = JointBounds(robot.lower, robot.upper, np.full(robot.nq, 1e3), robot.amax)
    q = 0.5 * (robot.lower + robot.upper)
    d = 1e-4
    q[5] = robot.upper[5] - d
    lb, ub = wide.compute(q, np.zeros(robot.nq), DT)
    a = robot.amax[5]
    assert ub[5] == pytest.approx(a * (np.sqrt(DT * DT + 2 * d / a) - DT))
    assert ub[5] * DT + ub[5] ** 2 / (2 * a) == pytest.approx(d)  # it can still stop at the limit
    assert lb[5] == pytest.approx(-a * DT)  # the other side: acceleration from rest


def test_outside_the_limits_the_joint_returns_at_vmax(robot, bounds):
    q = 0.5 * (robot.lower + robot.upper)
    q[4] = robot.lower[4] - 0.5
    q[6] = robot.upper[6] + 0.5
    lb, ub = bounds.compute(q, np.zeros(robot.nq), DT)
    assert lb[4] == ub[4] == pytest.approx(robot.vmax[4])
    assert lb[6] == ub[6] == pytest.approx(-robot.vmax[6])


def test_bad_limits_are_rejected(robot, bounds):
    n = robot.nq
    with pytest.raises(ValueError, match="lower must be <= upper"):
        JointBounds(robot.upper, robot.lower, robot.vmax, robot.amax)
    with pytest.raises(ValueError, match="finite and > 0"):
        JointBounds(robot.lower, robot.upper, np.zeros(n), robot.amax)
    with pytest.raises(ValueError, match="shape"):
        JointBounds(robot.lower, robot.upper, robot.vmax[:3], robot.amax)
    with pytest.raises(ValueError, match="dt"):
        bounds.compute(robot.q_rest, np.zeros(n), 0.0)


def test_compiled_box_gives_the_numpy_steps_bits():
    """``JointBounds(compiled=True)`` (``tick_kernel.velocity_box``) against the numpy steps, bit for bit: joints
    far from their stops (the numpy path skips the braking bound), near and past them, fast and at rest, random
    steps, with and without the measured-joint window (whose edges may also be crossed)."""
    rng = np.random.default_rng(11)
    n = 7
    lower, upper = -rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 2.0, n)
    args = (lower, upper, rng.uniform(2.0, 20.0, n), rng.uniform(20.0, 900.0, n))
    fast, ref = JointBounds(*args, compiled=True), JointBounds(*args)
    skipped = braked = 0
    for k in range(4000):
        span = 1.2 if k % 2 else 0.3  # odd draws reach and cross the stops, even ones stay mid-range
        q = rng.uniform(lower * span, upper * span)
        qd = rng.uniform(-25.0, 25.0, n) * rng.integers(0, 2)
        dt = rng.uniform(1e-4, 4e-3)
        window = None if k % 3 else (q - rng.uniform(-0.05, 0.3, n), q + rng.uniform(-0.05, 0.3, n))
        got = [x.copy() for x in fast.compute(q, qd, dt, window)]
        want = ref.compute(q, qd, dt, window)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        free = ref.braking_free(np.stack([q - lower, upper - q]), dt)
        skipped += free
        braked += not free
    assert skipped > 500 and braked > 500  # both of the numpy path's branches were compared
