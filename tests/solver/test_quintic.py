"""Quintic smoothing: boundary conditions and C2 continuity."""

from __future__ import annotations

import numpy as np

from services.solver.quintic import QuinticSmoother, quintic_coefficients


def _eval(c, s):
    p = sum(ci * s**i for i, ci in enumerate(c))
    v = sum(i * ci * s ** (i - 1) for i, ci in enumerate(c) if i)
    a = sum(i * (i - 1) * ci * s ** (i - 2) for i, ci in enumerate(c) if i > 1)
    return p, v, a


def test_coefficients_meet_both_end_states():
    rng = np.random.default_rng(0)
    p0, v0, a0, p1, v1, a1 = (rng.standard_normal(4) for _ in range(6))
    T = 0.37
    c = quintic_coefficients(p0, v0, a0, p1, v1, a1, T)
    for s, want in ((0.0, (p0, v0, a0)), (T, (p1, v1, a1))):
        for got, exp in zip(_eval(c, s), want):
            np.testing.assert_allclose(got, exp, atol=1e-9)


def test_smoother_is_c2_and_follows_constant_velocity_without_lag():
    dt = 0.002
    sm = QuinticSmoother(2, dt, 4)
    sm.reset(np.zeros(2))
    v = np.array([0.5, -0.2])
    q = np.zeros(2)
    for _ in range(400):
        q = q + v * dt
        sm.step(q, v)
    np.testing.assert_allclose(sm.v, v, atol=1e-9)
    np.testing.assert_allclose(sm.p, q, atol=1e-9)


def test_step_input_gives_a_c2_trajectory():
    """Published p, v, a agree with each other's differences: no jump in position, velocity or acceleration."""
    dt = 0.002
    sm = QuinticSmoother(1, dt, 10)
    sm.reset(np.zeros(1))
    target = np.array([0.01])
    p, v, a = [0.0], [0.0], [0.0]
    for _ in range(200):
        sm.step(target, np.zeros(1))
        p.append(sm.p[0])
        v.append(sm.v[0])
        a.append(sm.a[0])
    p, v, a = np.array(p), np.array(v), np.array(a)
    # Trapezoid rule between ticks: exact up to the jerk's variation, which is small against the values.
    np.testing.assert_allclose(np.diff(p), 0.5 * (v[1:] + v[:-1]) * dt, atol=0.02 * np.abs(p).max())
    np.testing.assert_allclose(np.diff(v), 0.5 * (a[1:] + a[:-1]) * dt, atol=0.1 * np.abs(v).max())
    assert abs(p[-1] - 0.01) < 1e-6
    # Without smoothing the same input is a position jump of 0.01 in one tick; here the largest step is far smaller.
    assert np.abs(np.diff(p)).max() < 0.5 * 0.01


def test_clamp_enforces_limits():
    dt = 0.002
    sm = QuinticSmoother(1, dt, 2)
    sm.reset(np.zeros(1))
    sm.step(np.array([1.0]), np.zeros(1))  # a huge jump
    n = sm.clamp(np.zeros(1), np.array([-1.0]), np.array([1.0]), np.array([2.0]))
    assert n == 1
    assert abs(sm.p[0]) <= 2.0 * dt + 1e-15 and abs(sm.v[0]) <= 2.0
