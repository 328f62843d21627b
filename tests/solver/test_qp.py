"""QP backends: DAQP's failures are decided again by PIQP before a caller drops a level."""

from __future__ import annotations

import numpy as np

from services.solver.qp import DaqpBackend, PiqpBackend


def _qp(seed: int = 3):
    """A feasible QP whose optimum has several active bounds and inequalities (n = 7)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(7, 7))
    H = A @ A.T + 1e-3 * np.eye(7)
    f = 5.0 * rng.normal(size=7)
    lb, ub = -0.2 * np.ones(7), 0.2 * np.ones(7)
    G = rng.normal(size=(4, 7))
    return H, f, lb, ub, G, -0.1 * np.ones(4), 0.1 * np.ones(4)


def test_a_problem_daqp_gives_up_on_is_solved_by_piqp_and_counted():
    H, f, lb, ub, G, gl, gu = _qp()
    reference = PiqpBackend().solve(H, f, lb, ub, G, gl, gu)
    assert reference.ok
    starved = DaqpBackend(iter_limit=1)  # DAQP stops before its active set is found
    starved.fallback = None
    assert not starved.solve(H, f, lb, ub, G, gl, gu).ok
    rescued = DaqpBackend(iter_limit=1)
    res = rescued.solve(H, f, lb, ub, G, gl, gu)
    assert res.ok and rescued.fallbacks == 1 and "solved by piqp" in res.status
    np.testing.assert_allclose(res.x, reference.x, atol=1e-7)
    assert np.all(res.x >= lb - 1e-7) and np.all(res.x <= ub + 1e-7)


def test_an_infeasible_problem_stays_a_failure():
    H, f, lb, ub, G, _, _ = _qp()
    G = np.vstack([G[:1], G[:1]])  # the same row asked to be >= 0.1 and <= -0.1
    res = DaqpBackend().solve(H, f, lb, ub, G, np.array([0.1, -1.0]), np.array([1.0, -0.1]))
    assert not res.ok
