"""Seed 002's planner, one constraint at a time, on the TITA-PiPER's hand kinematics."""

from __future__ import annotations

import math

import daqp
import numpy as np
import pytest

from services.solver.wbqp_accel import WbqpAccel, WbqpConfig, equality_qp, predict
from shared.kinematics.mobile_arm import ARM, BASE
from shared.robot.wheeled import build_wheeled_robot, planner_limits


@pytest.fixture(scope="module")
def robot():
    return build_wheeled_robot("tita_piper")


@pytest.fixture(params=["piqp", "daqp"])
def planner(request, robot):
    lo, hi = planner_limits(robot)
    return WbqpAccel(robot.kin, lo, hi, WbqpConfig(dt=0.001, qp=request.param))


#: The planner as seed 002 states it: without this project's two additions (velocity damper at the
#: limits, torso acceleration bound; tested in test_wbqp_reference.py), for the tests of the seed's terms.
SEED_ONLY = {"brake": (0.0,) * 7, "base_acc_max": 1e9}


def start(robot):
    return np.r_[robot.profile.start_base, robot.profile.start_arm], np.zeros(7)


def test_hand_jacobian_and_its_derivative_against_finite_differences(robot):
    kin = robot.kin
    rng = np.random.default_rng(2)
    h = 1e-6
    for _ in range(20):
        q = np.r_[rng.uniform(-1, 1, 2), 0.4, rng.uniform(-3, 3), rng.uniform([-2, 0.2, -2.8], [2, 3.0, -0.2])]
        qd = rng.normal(size=7)
        J = kin.jacobian(q)
        fd = np.column_stack([(kin.hand(q + h * e) - kin.hand(q - h * e)) / (2 * h) for e in np.eye(7)])
        assert np.abs(J - fd).max() < 1e-8
        # J̇_a q̇ = d/dt (J_a(q(t)) q̇) along q(t) = q + t q̇.
        jd_fd = (kin.jacobian(q + h * qd) @ qd - kin.jacobian(q - h * qd) @ qd) / (2 * h)
        assert np.abs(kin.jacobian_dot_qdot(q, qd) - jd_fd).max() < 1e-6
        # ... and it is not negligible at these speeds (the term matters).
        assert np.linalg.norm(jd_fd) > 1e-2
        p, Je, jde = kin.evaluate(q, qd)
        assert np.abs(p - kin.hand(q)).max() < 1e-14 and np.abs(Je - J).max() < 1e-14
        assert np.abs(jde - kin.jacobian_dot_qdot(q, qd)).max() < 1e-12


def test_hand_equality_holds_with_the_bias_term(robot, planner):
    """Eqs. 8-9: J_a q̈ = P̈ref - J̇_a q̇, so the hand's acceleration is exactly P̈ref."""
    q, _ = start(robot)
    qd = np.array([0.2, 0.0, -0.05, 0.3, 0.2, -0.4, 0.5])
    p = robot.kin.hand(q)
    # A turning torso needs a centripetal acceleration: start from a q̈_prev that has it (eq. 13).
    planner.reset(np.r_[0.0, qd[0] * qd[3], np.zeros(5)])
    res = planner.solve(q, qd, p + np.array([0.05, 0.02, -0.01]))
    assert res.status == "ok", res.reason
    J = robot.kin.jacobian(q)
    acc = J @ res.qdd + robot.kin.jacobian_dot_qdot(q, qd)
    assert np.abs(acc - res.pref_acc).max() < 1e-6 * (1 + np.linalg.norm(res.pref_acc))
    assert res.ee_residual < 1e-5


def test_reference_is_the_pd_law_of_eq_10(robot, planner):
    q, _ = start(robot)
    qd = np.array([0.1, 0, 0, 0, 0.1, 0.1, 0.1])
    p_d, v_d, a_d = np.array([0.3, 0.1, 0.9]), np.array([0.1, 0, 0]), np.array([0.0, 0.2, 0])
    pref, p, v = planner.reference(q, qd, p_d, v_d, a_d)
    assert p == pytest.approx(robot.kin.hand(q)) and v == pytest.approx(robot.kin.jacobian(q) @ qd)
    cfg = planner.config
    assert pref == pytest.approx(a_d + cfg.kp * (p_d - robot.kin.hand(q)) + cfg.kd * (v_d - robot.kin.jacobian(q) @ qd))


def test_position_limits_hold_through_the_prediction(robot, planner):
    """Eq. 11: an arm joint racing towards its stop and a torso sinking to its lowest height stop in time."""
    q, qd = start(robot)
    q[6] = planner.upper[6] - 0.002  # J3 2 mm-rad below its (margined) upper limit
    qd[6] = 3.0  # rad/s towards it
    q[2] = planner.lower[2] + 0.001
    qd[2] = -0.5
    dt = planner.config.dt
    for _ in range(50):
        res = planner.solve(q, qd, robot.kin.hand(q) + np.array([0.3, 0.0, -0.2]))
        q, qd = predict(q, qd, res.qdd, dt)
        assert q[6] <= planner.upper[6] + 1e-9
        assert q[2] >= planner.lower[2] - 1e-9
        assert np.all(q >= planner.lower - 1e-9) and np.all(q <= planner.upper + 1e-9)


def test_nonholonomic_constraint_no_sideways_torso_velocity(robot, planner):
    """Eq. 12 (velocity form): a hand target to the side turns the torso instead of sliding it."""
    q, qd = start(robot)
    q[3] = 0.4  # heading
    dt = planner.config.dt
    goal = robot.kin.hand(q) + np.array([0.0, 0.6, 0.0])
    moved = 0.0
    for _ in range(1500):
        res = planner.solve(q, qd, goal)
        q, qd = predict(q, qd, res.qdd, dt)
        lateral = -math.sin(q[3]) * qd[0] + math.cos(q[3]) * qd[1]
        assert abs(lateral) < 1e-6 * (1 + np.linalg.norm(qd[:2]))
        moved = max(moved, np.linalg.norm(qd[:2]))
    assert moved > 1e-3  # the torso did move (so the check above was not vacuous)


def test_torso_acceleration_change_is_bounded(robot, planner):
    """Eq. 13: |q̈_base - q̈_base,prev| <= ε every tick, even when the target jumps."""
    lo, hi = planner_limits(robot)
    planner = WbqpAccel(robot.kin, lo, hi, WbqpConfig(dt=planner.config.dt, qp=planner.config.qp, **SEED_ONLY))
    q, qd = start(robot)
    dt = planner.config.dt
    eps = np.asarray(planner.config.eps)
    prev = np.zeros(7)
    goal = robot.kin.hand(q) + np.array([0.5, 0.0, 0.0])
    jumped = False
    for _ in range(400):
        res = planner.solve(q, qd, goal)
        assert np.all(np.abs(res.qdd[BASE] - prev[BASE]) <= eps + 1e-9)
        jumped |= bool(np.any(np.abs(res.qdd[BASE] - prev[BASE]) >= eps - 1e-6))
        prev = res.qdd
        q, qd = predict(q, qd, res.qdd, dt)
    assert jumped  # the bound was active at least once


def test_torso_extends_the_arm_with_light_base_weights(robot):
    """Eq. 6's R: a heavy arm weight makes the torso carry the hand's motion, a heavy base weight the arm."""
    lo, hi = planner_limits(robot)
    q0, qd0 = start(robot)
    goal = robot.kin.hand(q0) + np.array([0.2, 0.0, 0.0])
    shares = []
    for r in ((1.0, 1.0, 20.0, 5.0, 50.0, 50.0, 50.0), (50.0, 50.0, 50.0, 50.0, 0.5, 0.5, 0.5)):
        pl = WbqpAccel(robot.kin, lo, hi, WbqpConfig(dt=0.001, r_weight=r, **SEED_ONLY))
        q, qd = q0.copy(), qd0.copy()
        for _ in range(500):
            q, qd = predict(q, qd, pl.solve(q, qd, goal).qdd, 0.001)
        shares.append((abs(q[0] - q0[0]), np.abs(q[ARM] - q0[ARM]).sum()))
    (base_a, arm_a), (base_b, arm_b) = shares
    assert base_a > 5 * base_b and arm_b > 5 * arm_a


def test_out_of_reach_falls_back_to_the_objective_and_says_so(robot, planner):
    """Section 4.1: a hand target 3 m up cannot be met; the hand task becomes the objective."""
    q, qd = start(robot)
    dt = planner.config.dt
    statuses = set()
    fallbacks = []
    for _ in range(300):
        res = planner.solve(q, qd, np.array([0.2, 0.0, 3.5]))
        statuses.add(res.status)
        if res.status == "infeasible":
            fallbacks.append(res)
        q, qd = predict(q, qd, res.qdd, dt)
        assert np.all(q >= planner.lower - 1e-9) and np.all(q <= planner.upper + 1e-9)
    assert "failed" not in statuses
    # Once the torso and arm run into their limits the equality cannot hold; the status says so.
    assert len(fallbacks) > 10
    assert all("objective" in r.reason and r.ee_residual > 1e-3 for r in fallbacks)
    # The hand still went up as far as it could: torso at its highest, arm pointing up.
    assert q[2] > planner.upper[2] - 0.05


def test_turning_from_rest_relaxes_eq_13_and_says_so(robot, planner):
    """A torso already turning with no centripetal acceleration planned: eq. 12 needs more than ε allows."""
    q, _ = start(robot)
    qd = np.array([0.5, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    res = planner.solve(q, qd, robot.kin.hand(q))
    assert res.status == "infeasible" and "eq. 13 relaxed" in res.reason
    q2, qd2 = predict(q, qd, res.qdd, planner.config.dt)
    assert abs(-math.sin(q2[3]) * qd2[0] + math.cos(q2[3]) * qd2[1]) < 1e-6


def test_config_is_validated():
    with pytest.raises(ValueError, match="r_weight"):
        WbqpConfig(r_weight=(1.0, 1.0))
    with pytest.raises(ValueError, match="dt"):
        WbqpConfig(dt=0.0)


def test_the_tick_integrates_its_plan(robot, planner):
    """solve() covers the whole tick: q_next, qd_next are eq. 7 applied to the planned q̈."""
    q, _ = start(robot)
    qd = np.array([0.1, 0.0, 0.0, 0.05, 0.2, -0.1, 0.1])
    planner.reset(np.r_[0.0, qd[0] * qd[3], np.zeros(5)])
    res = planner.solve(q, qd, robot.kin.hand(q) + np.array([0.05, 0.0, 0.02]))
    q2, qd2 = predict(q, qd, res.qdd, planner.config.dt)
    assert np.array_equal(res.q_next, q2) and np.array_equal(res.qd_next, qd2)
    assert not np.array_equal(q2, q)


def test_closed_form_equality_qp_is_the_qp_optimum():
    """equality_qp (no bound active) against DAQP on the same equality-constrained QP, and its refusals."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        h = rng.uniform(0.5, 50.0, 7)
        E = rng.normal(size=(4, 7))
        f, e = rng.normal(size=7), rng.normal(size=4)
        x = equality_qp((1.0 / h).tolist(), f.tolist(), E.tolist(), e.tolist())
        sense = np.full(4, 5, dtype=np.int32)  # DAQP equality rows
        ref, _, flag, _ = daqp.solve(np.diag(h), f, E, e, e, sense)
        assert flag == 1
        assert np.abs(np.array(x) - ref).max() <= 1e-9 * (1.0 + np.abs(ref).max())
        assert np.abs(E @ np.array(x) - e).max() <= 1e-10 * (1.0 + np.abs(e).max())
    E = rng.normal(size=(4, 7))
    E[3] = E[0] + E[1]  # rank 3: no unique multipliers
    assert equality_qp([1.0] * 7, [0.0] * 7, E.tolist(), [0.0] * 4) is None
