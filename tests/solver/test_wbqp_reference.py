"""What keeps mocap targets from shaking the TITA-PiPER: the reference filter, the velocity damper at
the position limits and the torso acceleration bound (services/solver/reference_filter.py, wbqp_accel.py)."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.reference_filter import ReferenceFilter
from services.solver.wbqp_accel import WbqpAccel, WbqpConfig, predict
from shared.robot.wheeled import build_wheeled_robot, planner_limits


@pytest.fixture(scope="module")
def robot():
    return build_wheeled_robot("tita_piper")


def test_filter_follows_a_step_without_overshoot_and_within_its_acceleration_bound():
    f = ReferenceFilter(omega=4.0, acc_max=1.0)
    f.reset(np.zeros(3))
    goal = np.array([0.3, -0.1, 0.05])
    ps, accs = [], []
    for _ in range(3000):  # 6 s at 2 ms
        p, _v, a = f.step(goal, np.zeros(3), 0.002)
        ps.append(p)
        accs.append(a)
    ps, accs = np.array(ps), np.array(accs)
    assert np.abs(accs).max() <= 1.0 + 1e-12
    assert np.abs(ps[-1] - goal).max() < 1e-3  # settled (6/ω = 1.5 s, plus the bounded start)
    # Critically damped: never past the goal on any axis.
    assert np.all((ps - goal) * np.sign(goal) <= 1e-9)


def test_filter_tracks_a_ramp_without_lag_given_its_velocity():
    f = ReferenceFilter(omega=4.0, acc_max=1.0)
    v = np.array([0.2, 0.0, 0.0])
    f.reset(np.zeros(3), v)
    for k in range(1, 1001):
        p, vo, _ = f.step(v * k * 0.002, v, 0.002)
    # Within one tick's travel (the semi-implicit step), not the 2 v / ω = 0.1 m of a filter without it.
    assert np.abs(p - v * 2.0).max() < 1e-3 and np.abs(vo - v).max() < 1e-5
    g = ReferenceFilter(omega=4.0, acc_max=1.0)
    g.reset(np.zeros(3), v)
    for k in range(1, 1001):
        p, _, _ = g.step(v * k * 0.002, np.zeros(3), 0.002)
    assert abs((v * 2.0 - p)[0] - 2 * 0.2 / 4.0) < 0.01


def test_filter_rejects_bad_settings():
    with pytest.raises(ValueError):
        ReferenceFilter(0.0, 1.0)
    with pytest.raises(ValueError):
        ReferenceFilter(4.0, -1.0)


def test_a_coordinate_running_into_its_limit_brakes_within_the_damper(robot):
    """Torso height rising at 0.1 m/s, 2 cm below its limit, with the hand target rising too.
    Without the damper eq. 11 lets it run into the limit and stop there in one tick, against
    eq. 13, and the hand equality hands that jolt to the arm (measured: z -18 000 m/s^2, arm
    8 200 rad/s^2); with it (brake 1 m/s^2) the torso slows on approach (measured: z -4.8 m/s^2,
    arm 900 rad/s^2)."""
    lo, hi = planner_limits(robot)
    peaks = {}
    for brake in (1.0, 0.0):
        cfg = WbqpConfig(dt=0.002, brake=(0.0, 0.0, brake, 0.0, 20.0, 20.0, 20.0))
        planner = WbqpAccel(robot.kin, lo, hi, cfg)
        q = np.r_[robot.profile.start_base, robot.profile.start_arm]
        q[2] = planner.upper[2] - 0.02
        qd = np.zeros(7)
        qd[2] = 0.1
        p0 = robot.kin.hand(q)
        z_acc, arm_acc = [], []
        for k in range(300):
            res = planner.solve(q, qd, p0 + np.array([0.0, 0.0, 0.1 * (k + 1) * 0.002]), np.array([0.0, 0.0, 0.1]))
            q, qd = predict(q, qd, res.qdd, cfg.dt)
            z_acc.append(res.qdd[2])
            arm_acc.append(np.abs(res.qdd[4:]).max())
            assert q[2] <= planner.upper[2] + 1e-9
        peaks[brake] = (-min(z_acc), max(arm_acc))
    assert peaks[1.0][0] < 10.0 and peaks[0.0][0] > 1000.0, peaks
    assert peaks[1.0][1] < peaks[0.0][1] / 5, peaks


def test_torso_acceleration_stays_within_its_bound(robot):
    lo, hi = planner_limits(robot)
    cfg = WbqpConfig(dt=0.002, base_acc_max=0.5)
    planner = WbqpAccel(robot.kin, lo, hi, cfg)
    q = np.r_[robot.profile.start_base, robot.profile.start_arm]
    qd = np.zeros(7)
    goal = robot.kin.hand(q) + np.array([1.0, 0.0, 0.0])  # a step far ahead: the torso must go
    acc = []
    for _ in range(1500):
        res = planner.solve(q, qd, goal)
        q, qd = predict(q, qd, res.qdd, cfg.dt)
        acc.append(res.qdd[:2])
    acc = np.array(acc)
    assert np.abs(acc).max() <= 0.5 + 1e-6
    assert q[0] > 0.3  # it still rolled towards the goal
