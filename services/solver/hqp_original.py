"""HQP-Original (seed 000, eq. 5): the stacked cascade.

Level k is solved over all n variables:

    min ||A_k x - b_k||^2 + eps ||x - mid||^2        (mid: the box centre)
    s.t. lb <= x <= ub                                  (5c)
         A_aug x = A_aug x*_{k-1}                       (5d)

where ``A_aug`` stacks the task matrices of every higher level and
``x*_{k-1}`` is the previous level's optimum. The rows of ``A_aug`` are
linearly dependent as soon as the stack is taller than its rank (the wrist
and elbow rows together exceed 17), which equality-constrained QP solvers
dislike, so (5d) is passed as ``E x = E x*`` with ``E`` an orthonormal basis
of the row space of ``A_aug`` (column-pivoted QR): the same set of x, no
redundant rows. There are no soft inequalities (5b, 5e) in this problem.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from services.solver.active_set import refine_on_active_set
from services.solver.base import QP_BOUND_TOL, LevelProblem, Solution, clip, within
from services.solver.cascade import RETRY_EPS, RETRY_WIDEN, CascadeQp
from services.solver.inequalities import NO_BOUND
from services.solver.linalg import split_row_space
from services.solver.qp import QpBackend


class HqpOriginal(CascadeQp):
    """Stacked-equality cascade HQP.

    Args:
        backend: QP backend (every level is a QP).
        eps: damping ``eps ||x||^2`` of each level (one value or one per level, the last repeats);
            the QP itself gets at least the backend's regularisation, which the refinement removes again.
        refine: refine each QP solution on its active set (default on, for both backends: the stacked
            equalities go to DAQP as a band).
    """

    name = "hqp-original"

    def __init__(self, backend: QpBackend, eps: float | Sequence[float] = 1e-9, refine: bool = True):
        super().__init__(backend, eps, refine)

    def solve_problem(self, p: LevelProblem) -> Solution:
        As, lb, ub, ineq, n = p.As, p.lb, p.ub, p.ineq, p.n
        # Solved in y = x - mid (mid: the box centre), so that the damping pulls towards the centre of the
        # box, as in HQP-Nullspace: with acceleration limits the box is a band around the last velocity.
        mid = p.mid
        lo, hi = lb - mid, ub - mid
        y = np.zeros(n)
        G = gl = gu = None
        if ineq is not None:
            # G x <= h in y: G y <= h - G mid
            G, gl, gu = ineq.G, np.full(ineq.rows, NO_BOUND), ineq.h - ineq.G @ mid
        iters = calls = 0
        reason = ""
        for k, (A, b) in enumerate(zip(As, p.bs)):
            eps = self.level_eps(k)
            c = b - A @ mid
            H = A.T @ A
            H.flat[:: n + 1] += max(eps, self.backend.regularization)
            f = -(A.T @ c)
            E = e = None
            if k > 0:
                split = split_row_space(np.vstack(As[:k]))
                if split.rank >= n:
                    break  # higher levels pin every variable
                E = np.ascontiguousarray(split.Q[:, : split.rank].T)
                e = E @ y
            r = self.backend.solve(H, f, lb=lo, ub=hi, G=G, gl=gl, gu=gu, E=E, e=e, key=f"orig{k}")
            if not r.ok:
                # Degenerate stacks can be called infeasible by an active-set solver: one retry,
                # better conditioned; the refinement below removes the extra regularisation's bias.
                H.flat[:: n + 1] += RETRY_EPS
                r2 = self.backend.solve(H, f, lb=lo, ub=hi, G=G, gl=gl, gu=gu, E=E, e=e, key=f"orig{k}")
                r2.iters += r.iters
                r = r2
            lo_k, hi_k, gu_k = lo, hi, gu
            if not r.ok:
                # The levels above left y on bounds, so this level's feasible set (box and E y = e) is a face
                # of zero width that round-off can make empty: one last try with the box, the rows and the
                # equalities (as a band) widened by RETRY_WIDEN; the refinement restores E y = e, the clip
                # below the box.
                lo_k, hi_k = lo - RETRY_WIDEN, hi + RETRY_WIDEN
                gu_k = None if gu is None else gu + RETRY_WIDEN
                Gw, glw, guw = G, gl, gu_k
                if E is not None:
                    Gw = E if G is None else np.vstack((G, E))
                    glw = e - RETRY_WIDEN if G is None else np.r_[gl, e - RETRY_WIDEN]
                    guw = e + RETRY_WIDEN if G is None else np.r_[gu_k, e + RETRY_WIDEN]
                r3 = self.backend.solve(H, f, lb=lo_k, ub=hi_k, G=Gw, gl=glw, gu=guw, key=f"orig{k}w")
                r3.iters += r.iters
                r = r3
            iters += r.iters
            calls += 1
            if not r.ok or not within(r.x, lo, hi, QP_BOUND_TOL) or (G is not None and np.any(G @ r.x > gu + 1e-7)):
                why = r.status if not r.ok else "QP left the box"
                if k == 0:
                    return p.solution(np.zeros(n), False, iters, calls, f"level 1 QP: {why}")
                reason = f"level {k + 1} QP {why}; kept levels 1-{k}"
                break
            if not self.refine:
                ys = r.x
            elif G is None:
                ys = refine_on_active_set(A, c, r.x, None, lo_k, hi_k, E, e, eps=eps)
            else:
                Gs = np.vstack((np.eye(n), G))
                ys = refine_on_active_set(A, c, r.x, Gs, np.r_[lo_k, gl], np.r_[hi_k, gu_k], E, e, eps=eps)
            y = clip(np.array(ys), lo, hi)
        return p.solution(clip(mid + y, lb, ub), True, iters, calls, reason)
