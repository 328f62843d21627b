"""Quintic smoothing: boundary conditions, C2 joints between segments, limits kept without breaking C2."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.solver.bounds import JointBounds
from services.solver.quintic import RAW_AMAX_FRACTION, RAW_VMAX_FRACTION, QuinticSmoother, quintic_coefficients

DT = 0.002


def _eval(c, s):
    """p, v, a of the polynomial sum c_i s^i at s (the test's own evaluation, not the smoother's)."""
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


def test_follows_constant_velocity_without_lag():
    sm = QuinticSmoother(2, DT, 4)
    sm.reset(np.zeros(2))
    v = np.array([0.5, -0.2])
    q = np.zeros(2)
    for _ in range(400):
        q = q + v * DT
        sm.step(q, v)
    np.testing.assert_allclose(sm.v, v, atol=1e-9)
    np.testing.assert_allclose(sm.p, q, atol=1e-9)
    np.testing.assert_allclose(sm.a, 0.0, atol=1e-6)


def _run_segments(sm, raw, steps):
    """Step through raw (q, qd) inputs with step lengths ``steps``; per segment, the state before, the
    segment end used and the state after.

    A step longer than the nominal tick is taken by the smoother in sub-steps of at most a tick (the
    limits hold at each): a copy stepped that way by hand must land on the same state, and its pieces
    are the segments recorded.
    """
    out = []
    for (q, qd), s in zip(raw, steps):
        n = max(1, math.ceil(s / sm.dt - 1e-9))
        twin = QuinticSmoother(len(sm.p), sm.dt, round(sm.T / sm.dt), sm.limits)
        twin.reset(sm.p, sm.v)
        twin.a[:] = sm.a
        clamped = sm.step(q, qd, s)
        for _ in range(n):
            before = (twin.p.copy(), twin.v.copy(), twin.a.copy())
            twin.step(q, qd, s / n)
            p1, v1 = twin.segment_end
            out.append((before, (p1.copy(), v1.copy()), (twin.p.copy(), twin.v.copy(), twin.a.copy()), s / n, clamped))
        for got, want in zip((sm.p, sm.v, sm.a), (twin.p, twin.v, twin.a)):
            np.testing.assert_array_equal(got, want)
    return out


def _assert_c2(records, T):
    """Each published state is the previous one's segment evaluated at the step: p, v and a continuous."""
    for (p0, v0, a0), (p1, v1), after, s, _ in records:
        c = quintic_coefficients(p0, v0, a0, p1, v1, np.zeros_like(p1), T)
        for got, want, what in zip(after, _eval(c, s), "pva"):
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9, err_msg=f"{what} jumps at a segment joint")


def test_step_input_gives_a_c2_trajectory_at_variable_steps():
    """A raw step of 0.01 rad, unlimited smoother, random step lengths (event ticks): C2 at every joint."""
    rng = np.random.default_rng(1)
    sm = QuinticSmoother(1, DT, 10)
    sm.reset(np.zeros(1))
    raw = [(np.array([0.01]), np.zeros(1))] * 300
    records = _run_segments(sm, raw, rng.uniform(0.3, 2.0, 300) * DT)
    _assert_c2(records, sm.T)
    p = np.array([r[2][0][0] for r in records])
    assert abs(p[-1] - 0.01) < 1e-6
    # Without smoothing the input is a jump of 0.01 in one tick; here the largest step is far smaller.
    assert np.abs(np.diff(p)).max() < 0.5 * 0.01


@pytest.fixture()
def limits():
    n = 3
    return JointBounds(np.full(n, -1.0), np.full(n, 1.0), np.full(n, 4.0), np.full(n, 40.0))


def test_limiter_keeps_every_limit_and_c2_on_violent_input(limits):
    """A raw trajectory slamming between the stops (bang-bang at its own bounds, the headroom the solver
    leaves) at random step lengths: every published sample respects the limits, the trajectory stays C2
    (the limiter moves segment ends, never the state), and the last-resort clamp never acts."""
    rng = np.random.default_rng(2)
    sm = QuinticSmoother(3, DT, 4, limits=limits)
    sm.reset(np.zeros(3))
    raw_bounds = JointBounds(
        limits.lower, limits.upper, RAW_VMAX_FRACTION * limits.vmax, RAW_AMAX_FRACTION * limits.amax
    )
    steps = rng.uniform(0.25, 2.0, 3000) * DT
    q, qd, raw = np.zeros(3), np.zeros(3), []
    for k, s in enumerate(steps):
        target = np.array([1.5, -1.5, 0.8]) * (1 if (k // 150) % 2 else -1) + 0.3 * rng.standard_normal(3)
        lb, ub = raw_bounds.compute(q, qd, s)
        qd = np.clip(200.0 * (target - q) + 50.0 * rng.standard_normal(3), lb, ub)
        q = np.clip(q + qd * s, limits.lower, limits.upper)
        raw.append((q.copy(), qd.copy()))
    records = _run_segments(sm, raw, steps)
    _assert_c2(records, sm.T)
    lim = limits
    for (p0, v0, _a0), _end, (p, v, a), s, clamped in records:
        assert clamped == 0
        assert np.all(p >= lim.lower - 1e-12) and np.all(p <= lim.upper + 1e-12)
        assert np.all(np.abs(v) <= lim.vmax + 1e-9)
        assert np.all(np.abs(p - p0) <= lim.vmax * s + 1e-12)
        assert np.all(np.abs(v - v0) <= lim.amax * s + 1e-9)
        assert np.all(np.abs(a) <= lim.amax + 1e-9)
    # The limits did bite: the joints reached their top speed and their stops.
    vs = np.array([r[2][1] for r in records])
    ps = np.array([r[2][0] for r in records])
    assert np.abs(vs).max() > 0.9 * 4.0 and np.abs(ps).max() > 0.9


def test_limiter_brakes_before_a_stop(limits):
    """Raw target beyond the upper stop at full speed: the smoothed joint decelerates at most at a_max and
    arrives at the stop at rest, without overshoot."""
    sm = QuinticSmoother(3, DT, 4, limits=limits)
    sm.reset(np.full(3, -0.9))
    ps, vs = [], []
    for _ in range(600):
        sm.step(np.full(3, 3.0), np.full(3, 4.0), DT)
        ps.append(sm.p[0])
        vs.append(sm.v[0])
    ps, vs = np.array(ps), np.array(vs)
    assert ps.max() <= 1.0 + 1e-12
    assert vs.max() > 3.5  # it did get going
    assert abs(ps[-1] - 1.0) < 1e-3 and abs(vs[-1]) < 1e-2
    assert np.abs(np.diff(vs)).max() <= 40.0 * DT + 1e-9


def test_compiled_limit_check_gives_the_numpy_paths_bits():
    """The compiled limit check (``tick_kernel``) against the numpy rows it replaces, on violent raw input at
    random step lengths and joints of different limits: the same state, bit for bit, every step, through ticks
    far from the stops, braking before them, with segment ends moved by the (compiled) line search and with
    joints it cannot save clamped."""
    n = 6
    rng = np.random.default_rng(5)
    lower, upper = -rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 2.0, n)
    lim = JointBounds(lower, upper, rng.uniform(2, 5, n), rng.uniform(200, 800, n))
    fast = QuinticSmoother(n, DT, 4, limits=lim)
    ref = QuinticSmoother(n, DT, 4, limits=lim, compiled=False)
    assert fast._kernel is not None and ref._kernel is None
    for sm in (fast, ref):
        sm.reset(np.zeros(n))
    raw_bounds = JointBounds(lim.lower, lim.upper, RAW_VMAX_FRACTION * lim.vmax, RAW_AMAX_FRACTION * lim.amax)
    q, qd = np.zeros(n), np.zeros(n)
    limited = free = clamped = 0
    for k, s in enumerate(rng.uniform(0.25, 2.0, 3000) * DT):
        # Mostly between the stops (free velocity rows), in bursts at them (braking rows).
        target = (1.2 if (k // 500) % 2 else 0.5) * lim.upper * np.sign(np.sin(k / 80.0 + np.arange(n)))
        lb, ub = raw_bounds.compute(q, qd, s)
        qd = np.clip(200.0 * (target - q) + 20.0 * rng.standard_normal(n), lb, ub)
        q = np.clip(q + qd * s, lim.lower, lim.upper)
        c = fast.step(q, qd, s)
        assert c == ref.step(q, qd, s)
        assert fast.limited == ref.limited
        # The clamped joints are named (the solver's reason text), the same by both paths, only when clamped.
        np.testing.assert_array_equal(fast.clamped_joints, ref.clamped_joints)
        assert (c > 0) == (fast.clamped_joints.size > 0) and fast.clamped_joints.size >= c
        clamped += c > 0
        np.testing.assert_array_equal(fast._S, ref._S)
        limited += fast.limited > 0
        free += ref._vmax_rows
    # Both branches of the velocity rows, the line search and its last-resort clamp were exercised.
    assert 100 < limited < 2900 and 100 < free < 2900 and 10 < clamped < limited
