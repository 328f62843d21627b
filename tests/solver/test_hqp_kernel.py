"""The compiled null-space recursion (``hqp_kernel``) against its numpy reference (``HqpNullspace(compiled=False)``)."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver import hqp_kernel
from services.solver.bench import clip_targets
from services.solver.core import SolverConfig, SolverCore
from services.solver.hqp_nullspace import HqpNullspace
from services.solver.inequalities import Inequalities
from services.solver.qp import DaqpBackend
from tests.support.lockstep import step_through

#: The service's per-level damping (SolverConfig.damping).
DAMPING = SolverConfig().damping


def _pair():
    return HqpNullspace(DaqpBackend(), eps=DAMPING, compiled=True), HqpNullspace(
        DaqpBackend(), eps=DAMPING, compiled=False
    )


def _random_levels(rng, n):
    """1-3 levels of 0..n+2 rows, some rank deficient, targets often beyond the box."""
    As, bs = [], []
    for _ in range(int(rng.integers(1, 4))):
        m = int(rng.integers(0, n + 3))
        A = rng.standard_normal((m, n))
        if m > 2 and rng.random() < 0.3:
            A[-1] = A[0] - 2.0 * A[1]  # a dependent row: the rank is revealed, not assumed
        As.append(A)
        bs.append(rng.uniform(0.1, 3.0) * rng.standard_normal(m))
    return As, bs


def test_kernel_equals_the_numpy_recursion_on_random_problems():
    """Same outcome (ok, QPs, reason, active bounds) and the same qd to round-off on 400 random stacks with the
    service's damping, including levels that need their QP (the kernel hands the level back and resumes).

    Round-off: the damped levels (eps 1e-5) amplify it by their condition number; the worst of these 400 is
    7e-9 rad/s, the median under 1e-12."""
    rng = np.random.default_rng(20261202)
    fast, ref = _pair()
    qp_levels = resumed = 0
    diffs = []
    for _ in range(400):
        n = int(rng.integers(4, 20))
        As, bs = _random_levels(rng, n)
        lb, ub = -rng.uniform(0.3, 3.0, n), rng.uniform(0.3, 3.0, n)
        a = ref.solve_matrices(As, bs, lb, ub)
        b = fast.solve_matrices(As, bs, lb, ub)
        assert (b.ok, b.qp_calls, b.reason, b.active) == (a.ok, a.qp_calls, a.reason, a.active)
        np.testing.assert_allclose(b.qd, a.qd, rtol=0, atol=2e-8)
        np.testing.assert_allclose(b.residuals, a.residuals, rtol=0, atol=2e-8)
        diffs.append(np.abs(b.qd - a.qd).max())
        qp_levels += a.qp_calls
        resumed += a.qp_calls > 0 and len(As) > 1
    # Both paths of the kernel are exercised: closed-form levels and QP levels it resumes after.
    assert qp_levels > 50 and resumed > 20
    assert np.median(diffs) < 1e-12


def test_kernel_keeps_inequality_rows_like_the_reference():
    """With coupling rows G qd <= h, an unconstrained optimum that breaks a row goes to the QP in both paths."""
    rng = np.random.default_rng(5)
    fast, ref = _pair()
    broke = 0
    for _ in range(100):
        n = 12
        As, bs = (
            [rng.standard_normal((6, n)), rng.standard_normal((8, n))],
            [rng.standard_normal(6), rng.standard_normal(8)],
        )
        lb, ub = -np.full(n, 2.0), np.full(n, 2.0)
        free = ref.solve_matrices(As, bs, lb, ub).qd
        G = rng.standard_normal((3, n))
        h = G @ free - 0.05  # the free optimum breaks every row
        rows = Inequalities(G, h)
        a = ref.solve_matrices(As, bs, lb, ub, rows)
        b = fast.solve_matrices(As, bs, lb, ub, rows)
        assert (b.ok, b.qp_calls, b.reason) == (a.ok, a.qp_calls, a.reason)
        np.testing.assert_allclose(b.qd, a.qd, rtol=0, atol=1e-8)
        broke += a.ok and bool(np.all(G @ b.qd <= h + 1e-7))
    assert broke > 90


def test_kernel_equals_the_reference_on_real_clip_ticks(bvh_clips, robot17):
    """Lockstep on a real retargeted clip: the shipped SolverCore (reference path) drives the trajectory and
    every tick's LevelProblem is solved by both paths. Ticks whose levels are all closed-form (no QP) agree to
    1e-9; QP ticks agree in level-1 residual (strict priority) unless one QP failed in either path."""
    frames = clip_targets([bvh_clips[0]])
    core = SolverCore(robot17, SolverConfig())
    ref = core.algorithm
    ref.compiled = False  # the reference drives
    fast = HqpNullspace(ref.backend, eps=ref.eps)
    closed, qp = [], []
    solve = ref.solve_problem

    def both(p):
        a = solve(p)
        b = fast.solve_matrices([x.copy() for x in p.As], [x.copy() for x in p.bs], p.lb.copy(), p.ub.copy(), p.ineq)
        # a's level-1 residual as solved: a saturation trade's caller then restates it against the demand it re-aimed
        (qp if a.qp_calls or b.qp_calls else closed).append((a, b, a.residuals[0] if a.residuals else None))
        return a

    ref.solve_problem = both
    step_through(core, frames)
    assert len(closed) > 100
    worst = max(np.abs(a.qd - b.qd).max() for a, b, _ in closed)
    assert worst <= 1e-9
    both_solved = [(a, b, r1) for a, b, r1 in qp if not a.reason and not b.reason]
    for _, b, r1 in both_solved:
        assert b.residuals[0] == pytest.approx(r1, abs=1e-6)
    assert len(both_solved) >= 0.9 * len(qp)


def test_no_tick_compiles_the_kernel_again(bvh_clips, robot17):
    """The kernel is compiled for one set of argument types when the algorithm is built (before a service is
    ready); real ticks, with self-collision rows (G comes from fancy indexing), must reuse that version, or
    a real-time tick would spend seconds compiling."""
    core = SolverCore(robot17, SolverConfig(self_collision=True))
    assert len(hqp_kernel.run_levels.signatures) == 1
    alg = core.algorithm
    solve = alg.solve_problem
    with_rows = []

    def spy(p):
        with_rows.append(p.ineq is not None)
        return solve(p)

    alg.solve_problem = spy
    t = 0.0
    for clip in bvh_clips:
        for msg in clip_targets([clip])[:150]:
            core.step(msg, None, t)
            t += core.dt
        if sum(with_rows) >= 5:
            break
    assert sum(with_rows) >= 5
    assert len(hqp_kernel.run_levels.signatures) == 1
