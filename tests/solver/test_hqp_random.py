"""Strict priorities on random problems (issue 5 item 4): random Jacobians, targets and boxes that are often active."""

from __future__ import annotations

import numpy as np
import pytest
from lexref import lexicographic_reference
from scipy.optimize import lsq_linear

from services.solver.hqp_nullspace import HqpNullspace
from services.solver.hqp_original import HqpOriginal
from services.solver.qp import DaqpBackend, PiqpBackend
from services.solver.wqp import WeightedQp

N_PROBLEMS = 500
TOL = 1e-6


def random_problem(rng: np.random.Generator, n_max: int = 5):
    """Two levels over n <= n_max variables; targets large against the box so bounds are often active."""
    n = int(rng.integers(3, n_max + 1))
    m1 = int(rng.integers(1, n))
    m2 = int(rng.integers(1, n + 1))
    A1 = rng.standard_normal((m1, n))
    A2 = rng.standard_normal((m2, n))
    b1 = 2.0 * rng.standard_normal(m1)
    b2 = 2.0 * rng.standard_normal(m2)
    lb = -rng.uniform(0.05, 1.5, n)
    ub = rng.uniform(0.05, 1.5, n)
    return A1, b1, A2, b2, lb, ub


@pytest.fixture(scope="module")
def problems():
    rng = np.random.default_rng(20261122)
    return [random_problem(rng) for _ in range(N_PROBLEMS)]


@pytest.fixture(scope="module")
def references(problems):
    return [lexicographic_reference(*p) for p in problems]


@pytest.mark.parametrize("backend", [PiqpBackend, DaqpBackend], ids=["piqp", "daqp"])
def test_nullspace_equals_original_and_brute_force(problems, references, backend):
    ns = HqpNullspace(backend())
    orig = HqpOriginal(PiqpBackend())
    active = 0
    for (A1, b1, A2, b2, lb, ub), ref in zip(problems, references):
        s_ns = ns.solve_matrices([A1, A2], [b1, b2], lb, ub)
        s_or = orig.solve_matrices([A1, A2], [b1, b2], lb, ub)
        assert s_ns.ok and s_or.ok
        assert np.all(s_ns.qd >= lb - 1e-12) and np.all(s_ns.qd <= ub + 1e-12)
        np.testing.assert_allclose(s_ns.residuals, s_or.residuals, atol=TOL)
        np.testing.assert_allclose(s_ns.residuals, ref, atol=TOL)
        active += s_ns.active > 0
    # The boxes must really bite, or the test would prove nothing about hard limits.
    assert active > N_PROBLEMS // 2


def test_adding_a_level_never_degrades_level_one(problems):
    ns = HqpNullspace(DaqpBackend())
    for A1, b1, A2, b2, lb, ub in problems:
        alone = ns.solve_matrices([A1], [b1], lb, ub).residuals[0]
        both = ns.solve_matrices([A1, A2], [b1, b2], lb, ub).residuals[0]
        assert both <= alone + TOL


def test_larger_problems_nullspace_equals_original():
    """Robot-sized stacks (17 variables, 12 + 6 + 17 rows, three levels) on random data."""
    rng = np.random.default_rng(7)
    ns = HqpNullspace(DaqpBackend())
    orig = HqpOriginal(PiqpBackend())
    for _ in range(60):
        n = 17
        As = [rng.standard_normal((12, n)), rng.standard_normal((6, n)), 0.1 * np.eye(n)]
        bs = [3.0 * rng.standard_normal(12), 3.0 * rng.standard_normal(6), rng.standard_normal(n)]
        lb, ub = -rng.uniform(0.1, 1.0, n), rng.uniform(0.1, 1.0, n)
        s_ns = ns.solve_matrices(As, bs, lb, ub)
        s_or = orig.solve_matrices(As, bs, lb, ub)
        np.testing.assert_allclose(s_ns.residuals, s_or.residuals, atol=TOL)


def test_wqp_tracks_level_one_worse_when_levels_conflict(problems, references):
    ns = HqpNullspace(DaqpBackend())
    wqp = WeightedQp(DaqpBackend(), level_weights=(1.0, 0.3))
    conflicts = 0
    for (A1, b1, A2, b2, lb, ub), (_r1, r2) in zip(problems, references):
        h = ns.solve_matrices([A1, A2], [b1, b2], lb, ub).residuals
        w = wqp.solve_matrices([A1, A2], [b1, b2], lb, ub).residuals
        assert w[0] >= h[0] - TOL  # level 1 is optimal in the HQP: nothing beats it
        # Conflict: level 2 alone could do better than it can on level 1's optimal set.
        alone = lsq_linear(A2, b2, bounds=(lb, ub), tol=1e-12)
        r2_alone = float(np.linalg.norm(A2 @ alone.x - b2))
        if h[0] < 1e-9 and r2 > r2_alone + 1e-3:
            conflicts += 1
            assert w[0] > h[0] + 1e-6, "the weighted QP must give up some level-1 tracking"
    assert conflicts > 50
