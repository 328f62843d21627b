"""HQP-Nullspace (seed 000, section 3; ARCHITECTURE "Solving"): strict priorities by null-space recursion.

    x = 0; Z = I
    for each level k:
        x0 = x + Z Z^T (mid - x)               (nearest the box centre mid = (lb + ub) / 2)
        w* = argmin ||A_k (x0 + Z w) - b_k||^2 + eps ||w||^2   s.t.  lb <= x0 + Z w <= ub
        x = x0 + Z w*
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
from scipy.linalg import lapack

from services.solver.active_set import refine_on_active_set
from services.solver.base import FEASIBLE_TOL, QP_BOUND_TOL, LevelProblem, Solution, clip, violation, within
from services.solver.cascade import LAST_RETRY_WIDEN, RETRY_EPS, RETRY_WIDEN, CascadeQp
from services.solver.inequalities import level_rows
from services.solver.linalg import split_row_space
from services.solver.qp import QpBackend

#: "No inequality rows" for the kernel: G (0, 1) and h (0,) (never indexed).
_NO_G, _NO_H = np.zeros((0, 1)), np.zeros(0)


class HqpNullspace(CascadeQp):
    """Null-space recursive HQP.

    Args:
        backend, eps, refine: see :class:`CascadeQp` (the shortcut and the QP solve the same damped problem).
        shortcut: try the unconstrained optimum before calling the QP.
        compiled: run the recursion in the numba kernel (``hqp_kernel``, compiled when built); False runs the
            numpy path, the readable reference the kernel is tested against. Both hand QP levels to ``backend``.
    """

    name = "hqp-nullspace"

    def __init__(
        self,
        backend: QpBackend,
        eps: float | Sequence[float] = 1e-9,
        shortcut: bool = True,
        refine: bool | None = None,
        compiled: bool = True,
    ) -> None:
        super().__init__(backend, eps, refine)
        self.shortcut = shortcut
        #: Run the recursion in the compiled kernel (``hqp_kernel``); False: the numpy reference path.
        self.compiled = compiled
        #: Level QPs solved only on the box widened by ``RETRY_WIDEN`` (see :meth:`_level_qp`), since built.
        self.widened = 0
        self._kernel = self._load_kernel() if compiled else None
        self._ws = None
        self._eps_key: tuple | None = None
        self._eps_arr = np.zeros(0)

    def solve_problem(self, p: LevelProblem) -> Solution:
        if self.compiled and self.shortcut:
            return self._solve_compiled(p)
        return self._solve_numpy(p)

    def _load_kernel(self):
        """The kernel module, compiled (or loaded from its cache) now, not on a real-time tick. Imported here, so
        that processes without this solver do not load numba."""
        from services.solver import hqp_kernel

        hqp_kernel.warm_up()
        self._kernel = hqp_kernel
        return hqp_kernel

    def _solve_compiled(self, p: LevelProblem) -> Solution:
        """The recursion of :meth:`_solve_numpy` in the compiled kernel (``hqp_kernel``), the QPs here."""
        hqp_kernel = self._kernel if self._kernel is not None else self._load_kernel()
        n = p.n
        A, b, offs, rows_max = self._stacked(p)
        L = offs.shape[0] - 1
        ws = self._ws
        if ws is None or ws.n != n or ws.m < rows_max or ws.levels < L:
            ws = self._ws = hqp_kernel.Workspace(n, max(rows_max, n), L)
        if self._eps_key != (self.eps, L):
            self._eps_key = (self.eps, L)
            self._eps_arr = np.array([self.level_eps(k) for k in range(L)])
        ineq = p.ineq
        # C-ordered float64 everywhere: the kernel is compiled for exactly these types once (warm_up), and
        # another layout (a fancy-indexed G) would compile a second version on a real-time tick.
        G, h = (_c(ineq.G), _c(ineq.h)) if ineq is not None else (_NO_G, _NO_H)
        lb, ub = _c(p.lb), _c(p.ub)
        st = ws.state
        st[:] = 0
        st[hqp_kernel.ST_COLS] = -1
        iters = calls = 0
        resume = False
        while hqp_kernel.run_levels(A, b, offs, lb, ub, self._eps_arr, G, h, ws.W, ws.I, resume):
            if st[hqp_kernel.ST_STATUS] == hqp_kernel.SINGULAR:
                raise np.linalg.LinAlgError("hqp kernel: singular damped normal equations")
            # This level's unconstrained optimum broke a bound: its QP, as in the numpy path.
            k, r, m = int(st[hqp_kernel.ST_LEVEL]), int(st[hqp_kernel.ST_COLS]), int(st[hqp_kernel.ST_ROWS])
            Z = None if r < 0 else ws.Z[:, :r]
            M = ws.M[:m, : n if r < 0 else r]
            c = ws.c[:m]
            base = ws.base
            lo, hi = lb - base, ub - base
            w, its, status, widen = self._level_qp(M, c, Z, lo, hi, k, level_rows(ineq, Z, base, lo, hi))
            iters += its
            calls += 1
            if w is None:
                reason = f"level 1 QP: {status}" if k == 0 else f"level {k + 1} QP {status}; kept levels 1-{k}"
                return p.solution(ws.x.copy(), k != 0, iters, calls, reason)
            xt = base + (w if Z is None else Z @ w)
            tol = QP_BOUND_TOL + widen
            if not within(xt, lb, ub, tol) or (ineq is not None and not ineq.satisfied(xt, tol)):
                gap = max(violation(xt, lb, ub), ineq.violation(xt) if ineq is not None else 0.0)
                return p.solution(ws.x.copy(), k != 0, iters, calls, f"level {k + 1} QP left the box by {gap:.2e}")
            ws.x[:] = clip(xt, lb, ub)
            resume = True
        return Solution(ws.x.copy(), ws.res[:L].tolist(), True, iters, calls, int(st[hqp_kernel.ST_ACTIVE]), "")

    def _stacked(self, p: LevelProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Every level's rows as one (sum m_k, n) matrix and (sum m_k,) vector, the (L + 1,) level offsets
        and the most rows on a level (the LevelStack's own buffers when p came from it)."""
        stack = self._stack
        if stack is not None and p.As is stack.A:
            return stack.A_all, stack.b_all, stack.offsets, stack.max_rows
        n = p.n
        sizes = [a.shape[0] for a in p.As]
        offs = np.cumsum([0, *sizes]).astype(np.int64)
        A = np.vstack([np.asarray(a, dtype=float).reshape(-1, n) for a in p.As])
        b = np.concatenate([np.asarray(v, dtype=float).reshape(-1) for v in p.bs])
        return A, b, offs, max(sizes)

    def _solve_numpy(self, p: LevelProblem) -> Solution:
        """The readable reference of the recursion (numpy and LAPACK calls), the oracle of the kernel's tests."""
        As, bs, lb, ub, ineq = p.As, p.bs, p.lb, p.ub, p.ineq
        x = np.zeros(p.n)
        # Damping pulls towards the centre of the box rather than towards zero: with acceleration limits the
        # box is a narrow band around the last velocity, and the zero-velocity side of it would push the
        # unconstrained optimum out of it (a QP on every tick instead of a few).
        mid = p.mid
        # The box widened by the feasibility tolerance, once for every level's shortcut check (``within``).
        lo_tol = lb - FEASIBLE_TOL
        hi_tol = ub + FEASIBLE_TOL
        Z: np.ndarray | None = None  # None means identity (first level)
        iters = calls = 0
        reason = ""
        for k, (A, b) in enumerate(zip(As, bs)):
            if Z is not None and Z.shape[1] == 0:
                break  # no freedom left for lower levels
            # This level moves x + Z w around base, the point of x + range(Z) nearest the box centre.
            if Z is None:
                base, M = mid, A
            else:
                base = x + Z @ (Z.T @ (mid - x))
                M = A @ Z
            c = b - A @ base
            last = k == len(As) - 1
            # The last level needs no null space: its damped optimum comes from the normal equations.
            eps = self.level_eps(k)
            split = None if last and eps > 0 else split_row_space(M)
            xt = None
            if self.shortcut:
                w = _damped_lstsq(M, c, eps) if split is None else split.lstsq(c, eps)
                xt = base + (w if Z is None else Z @ w)
                if ((xt < lo_tol) | (xt > hi_tol)).any() or (ineq is not None and not ineq.satisfied(xt)):
                    xt = None
            if xt is None:
                rows = level_rows(ineq, Z, base, lb - base, ub - base)
                w, its, status, widen = self._level_qp(M, c, Z, lb - base, ub - base, k, rows)
                iters += its
                calls += 1
                if w is None:
                    if k == 0:
                        return p.solution(x, False, iters, calls, f"level 1 QP: {status}")
                    reason = f"level {k + 1} QP {status}; kept levels 1-{k}"
                    break
                xt = base + (w if Z is None else Z @ w)
                # Within the QP's own tolerance (and the retry's widening): snap onto the box.
                tol = QP_BOUND_TOL + widen
                if not within(xt, lb, ub, tol) or (ineq is not None and not ineq.satisfied(xt, tol)):
                    gap = max(violation(xt, lb, ub), ineq.violation(xt) if ineq is not None else 0.0)
                    reason = f"level {k + 1} QP left the box by {gap:.2e}"
                    if k == 0:
                        return p.solution(x, False, iters, calls, reason)
                    break
                clip(xt, lb, ub)
            x = xt
            if last:
                break
            N = split.null_basis
            Z = N if Z is None else Z @ N
        return p.solution(x, True, iters, calls, reason)

    def _level_qp(self, M, c, Z, lo, hi, k, rows=(None, None, None)):
        """QP of one level in z: ``min ||M z - c||^2 + eps ||z||^2``, ``lo <= Z z <= hi`` (Z None = identity).

        ``rows``: the box and the inequality rows as one stack ``gl <= G z <= gu`` (``level_rows``), or
        Nones when there are no inequality rows.

        A dual active-set solver can call a degenerate, nearly singular level infeasible; it is retried
        once with ``RETRY_EPS`` regularisation and refined on its active set, which removes that bias again.
        When both fail, both are tried once more on the box (and rows) widened by ``RETRY_WIDEN``, then by
        ``LAST_RETRY_WIDEN``: a level whose feasible set touches bounds the levels above sit on is otherwise lost
        to round-off. The caller accepts the result within that widening and clips it back onto the box. Only
        failed levels reach the retries, so every other tick is unchanged.

        Returns:
            (z or None, iterations, status text, the widening [rad/s] of the box the answer was found in).
        """
        iters = 0
        status = ""
        eps0 = self.level_eps(k)
        G, gl, gu = rows
        attempts = ((eps0, self.refine, 0.0), (max(RETRY_EPS, eps0), True, 0.0))
        MtM = M.T @ M
        f = -(M.T @ c)
        tiers = (*attempts, *((e, r, w) for w in (RETRY_WIDEN, LAST_RETRY_WIDEN) for e, r, _ in attempts))
        for eps, refine, widen in tiers:
            lo_w, hi_w = (lo - widen, hi + widen) if widen else (lo, hi)
            gl_w, gu_w = (gl - widen, gu + widen) if widen and G is not None else (gl, gu)
            H = MtM.copy()
            H.flat[:: H.shape[0] + 1] += eps
            if G is not None:
                r = self.backend.solve(H, f, G=G, gl=gl_w, gu=gu_w, key=f"ns{k}g")
            elif Z is None:
                r = self.backend.solve(H, f, lb=lo_w, ub=hi_w, key=f"ns{k}")
            else:
                r = self.backend.solve(H, f, G=Z, gl=lo_w, gu=hi_w, key=f"ns{k}")
            iters += r.iters
            status = r.status
            if r.ok:
                if widen:
                    self.widened += 1
                if not refine:
                    return r.x, iters, status, widen
                if G is not None:
                    return refine_on_active_set(M, c, r.x, G, gl_w, gu_w, eps=eps0), iters, status, widen
                return refine_on_active_set(M, c, r.x, Z, lo_w, hi_w, eps=eps0), iters, status, widen
        return None, iters, status, 0.0


def _c(a: np.ndarray) -> np.ndarray:
    """a as a C-ordered float64 array (itself when it is one)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _damped_lstsq(M: np.ndarray, c: np.ndarray, eps: float) -> np.ndarray:
    """argmin ||M w - c||^2 + eps ||w||^2 for eps > 0: (M^T M + eps I) w = M^T c (positive definite)."""
    H = M.T @ M
    H.flat[:: H.shape[0] + 1] += eps
    _c, w, info = lapack.dposv(H, M.T @ c)
    if info != 0:
        raise np.linalg.LinAlgError(f"dposv failed with info={info}")
    return w
