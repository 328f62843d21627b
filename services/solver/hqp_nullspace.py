"""HQP-Nullspace (seed 000, section 3; ARCHITECTURE "Solving"): strict priorities by null-space recursion.

    x = 0; Z = I
    for each level k:
        z* = argmin ||A_k (x + Z z) - b_k||^2 + eps ||z||^2   s.t.  lb <= x + Z z <= ub
        x = x + Z z*
        Z = Z null(A_k Z)        (column-pivoted QR, rank-revealing)

Each level only moves inside the null space of every level above it, so it can
never change their task values; the joint bounds are hard at every level, so a
level that cannot be met keeps its least-squares optimum. The optimal task
value ``A_k x*`` of a convex least-squares level is unique, hence its optimal
set is exactly ``{x in box : A_k x = A_k x*}``, which ``x + Z null(A_k Z) w``
plus the box parametrises: the recursion is the exact lexicographic optimum.

Shortcut: the unconstrained minimum-norm solution of a level comes for free
from the QR that gives the null space; when it respects the bounds it is the
constrained optimum too and no QP is solved.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from services.solver.active_set import refine_on_active_set
from services.solver.base import (
    QP_BOUND_TOL,
    Solution,
    clip,
    count_active,
    level_residuals,
    violation,
    within,
)
from services.solver.cascade import RETRY_EPS, CascadeQp
from services.solver.inequalities import Inequalities, level_rows
from services.solver.linalg import split_row_space
from services.solver.qp import QpBackend


class HqpNullspace(CascadeQp):
    """Null-space recursive HQP.

    Args:
        backend, eps, refine: see :class:`CascadeQp` (the shortcut and the QP solve the same damped problem).
        shortcut: try the unconstrained optimum before calling the QP.
    """

    name = "hqp-nullspace"

    def __init__(
        self,
        backend: QpBackend,
        eps: float | Sequence[float] = 1e-9,
        shortcut: bool = True,
        refine: bool | None = None,
    ) -> None:
        super().__init__(backend, eps, refine)
        self.shortcut = shortcut

    def solve_matrices(
        self,
        As: Sequence[np.ndarray],
        bs: Sequence[np.ndarray],
        lb: np.ndarray,
        ub: np.ndarray,
        ineq: Inequalities | None = None,
    ):
        n = lb.shape[0]
        if ineq is not None and not ineq.rows:
            ineq = None
        x = np.zeros(n)
        Z: np.ndarray | None = None  # None means identity (first level)
        iters = calls = 0
        reason = ""
        for k, (A, b) in enumerate(zip(As, bs)):
            if Z is not None and Z.shape[1] == 0:
                break  # no freedom left for lower levels
            if Z is None:
                M, c = A, b
            else:
                M, c = A @ Z, b - A @ x
            split = split_row_space(M)
            xt = None
            if self.shortcut:
                z = split.lstsq(c, self.level_eps(k))
                xt = x + (z if Z is None else Z @ z)
                if not within(xt, lb, ub) or (ineq is not None and not ineq.satisfied(xt)):
                    xt = None
            if xt is None:
                z, its, status = self._level_qp(M, c, Z, lb - x, ub - x, k, level_rows(ineq, Z, x, lb - x, ub - x))
                iters += its
                calls += 1
                if z is None:
                    if k == 0:
                        return Solution(x, level_residuals(As, bs, x), False, iters, calls, 0, f"level 1 QP: {status}")
                    reason = f"level {k + 1} QP {status}; kept levels 1-{k}"
                    break
                xt = x + (z if Z is None else Z @ z)
                # Within the QP's own tolerance: snap onto the box.
                if not within(xt, lb, ub, QP_BOUND_TOL) or (ineq is not None and not ineq.satisfied(xt, QP_BOUND_TOL)):
                    gap = max(violation(xt, lb, ub), ineq.violation(xt) if ineq is not None else 0.0)
                    reason = f"level {k + 1} QP left the box by {gap:.2e}"
                    if k == 0:
                        return Solution(x, level_residuals(As, bs, x), False, iters, calls, 0, reason)
                    break
                clip(xt, lb, ub)
            x = xt
            N = split.null_basis
            Z = N if Z is None else Z @ N
        return Solution(x, level_residuals(As, bs, x), True, iters, calls, count_active(x, lb, ub), reason)

    def _level_qp(self, M, c, Z, lo, hi, k, rows=(None, None, None)):
        """QP of one level in z: ``min ||M z - c||^2 + eps ||z||^2``, ``lo <= Z z <= hi`` (Z None = identity).

        ``rows``: the box and the inequality rows as one stack ``gl <= G z <= gu`` (``level_rows``), or
        Nones when there are no inequality rows.

        A dual active-set solver can call a degenerate, nearly singular level infeasible; it is retried
        once with ``RETRY_EPS`` regularisation and refined on its active set, which removes that bias again.

        Returns:
            (z or None, iterations, status text).
        """
        iters = 0
        status = ""
        eps0 = self.level_eps(k)
        for eps, refine in ((eps0, self.refine), (max(RETRY_EPS, eps0), True)):
            H = M.T @ M
            H.flat[:: H.shape[0] + 1] += eps
            f = -(M.T @ c)
            G, gl, gu = rows
            if G is not None:
                r = self.backend.solve(H, f, G=G, gl=gl, gu=gu, key=f"ns{k}g")
            elif Z is None:
                r = self.backend.solve(H, f, lb=lo, ub=hi, key=f"ns{k}")
            else:
                r = self.backend.solve(H, f, G=Z, gl=lo, gu=hi, key=f"ns{k}")
            iters += r.iters
            status = r.status
            if r.ok:
                if not refine:
                    return r.x, iters, status
                if G is not None:
                    return refine_on_active_set(M, c, r.x, G, gl, gu, eps=eps0), iters, status
                return refine_on_active_set(M, c, r.x, Z, lo, hi, eps=eps0), iters, status
        return None, iters, status
