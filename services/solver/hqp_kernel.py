"""The null-space HQP recursion compiled with numba: the same levels as ``HqpNullspace``'s numpy path.

Why compiled: the recursion is about 20 numpy/LAPACK calls a level (QR, Q, damped solves, projections)
of 2-4 us each for under 20 kflop of arithmetic; the call overhead, not the arithmetic, set the tick's
floor (issue 13, h13s). Here one call runs every level whose unconstrained optimum is inside the box
over preallocated arrays, and returns to Python only for a level that needs its QP (DAQP, with the PIQP
fallback, stays the QP) or when done. The numpy path (``HqpNullspace(compiled=False)``) stays the
readable reference; the tests hold this kernel to it.

The linear algebra is the numpy path's, written out for these small sizes (n <= ~40 joints, m <= ~60
rows a level): a column-pivoted Householder QR of ``M^T`` (LAPACK ``dgeqp3``'s pivoting and reflector
convention, with exact column norms instead of their down-dating), the same rank rule
(``linalg.RANK_RTOL`` / ``RANK_ATOL``), the damped least squares on the revealed row space, and the
damped normal equations on the last level. Results equal the numpy path's to round-off: a null-space
basis is unique only up to an orthogonal change, which neither the next level's damped optimum nor its
QP depend on.

Compilation: ``cache=True`` writes the machine code next to this file (``__pycache__``) or under
``NUMBA_CACHE_DIR``; :func:`warm_up` compiles (or loads) it, and the solver service calls it before it
says it is ready, so no real-time tick pays for it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from services.solver.base import FEASIBLE_TOL
from services.solver.linalg import RANK_ATOL, RANK_RTOL

#: ``state`` slots shared by the kernel and its caller.
ST_LEVEL, ST_COLS, ST_RANK, ST_ROWS, ST_STATUS, ST_ACTIVE = range(6)
_ST_SIZE = 6
#: Kernel outcomes (``state[ST_STATUS]``).
DONE, NEEDS_QP, SINGULAR = 0, 1, 2


class Workspace:
    """Preallocated arrays of one problem size (n joints, at most m >= n rows a level, L levels), carved out
    of two flat buffers so that a kernel call passes two arrays instead of fifteen (numba's dispatch costs
    about 0.3 us an argument).

    Attributes (views into ``W``, float64, and ``I``, int64):
        x: (n,) solution of the levels so far [rad/s]. base: (n,) point the current level moves around.
        Z: (n, n) null-space basis of the levels so far in its first ``state[ST_COLS]`` columns (-1 = identity).
        M: (m, n) the current level's ``A Z`` in its first rows/columns. c: (m,) its target ``b - A base``.
        res: (L,) every level's residual of the final x. state: (6,) (``ST_*``).
        The rest is the kernel's scratch (QR, Q, Gram matrix, vectors, pivots).
    """

    def __init__(self, n: int, m: int, levels: int):
        self.n, self.m, self.levels = n, m, levels
        self.W = np.zeros(_float_size(n, m, levels))
        self.I = np.zeros(_ST_SIZE + m, dtype=np.int64)
        o = 0
        views = []
        for size, shape in ((n, (n,)), (n, (n,)), (n * n, (n, n)), (m * n, (m, n)), (m, (m,)), (levels, (levels,))):
            views.append(self.W[o : o + size].reshape(shape))
            o += size
        self.x, self.base, self.Z, self.M, self.c, self.res = views
        self.state = self.I[:_ST_SIZE]


def _float_size(n: int, m: int, levels: int) -> int:
    """Length of the float buffer: x, base, Z, M, c, res, then scratch (qr (m, n), tau, Q, tmp, 4 vectors)."""
    return 2 * n + n * n + m * n + m + levels + m * n + n + 2 * n * n + 4 * max(n, m)


@njit(cache=True)
def _pivoted_qr(a, r, m, tau, piv, norms):
    """Column-pivoted Householder QR of ``X = a[:m, :r]^T`` (r, m) in place (``dgeqp3``'s convention).

    a (m, r) holds X transposed, so each column of X is a contiguous row of a: afterwards ``R[i, p] =
    a[p, i]`` for p >= i and reflector j is ``v = (1, a[j, j+1:r])``. Returns min(r, m).
    """
    k = min(r, m)
    for j in range(m):
        piv[j] = j
    for j in range(k):
        # The remaining column with the largest norm below row j (first on ties, as idamax).
        best = -1.0
        p = j
        for col in range(j, m):
            s = 0.0
            for i in range(j, r):
                s += a[col, i] * a[col, i]
            norms[col] = s
            if s > best:
                best = s
                p = col
        if p != j:
            for i in range(r):
                t = a[j, i]
                a[j, i] = a[p, i]
                a[p, i] = t
            t2 = piv[j]
            piv[j] = piv[p]
            piv[p] = t2
        # Householder reflector H = I - tau v v^T with v[0] = 1 (dlarfg): H X[j:, j] = (beta, 0, ...).
        alpha = a[j, j]
        xn = 0.0
        for i in range(j + 1, r):
            xn += a[j, i] * a[j, i]
        if xn == 0.0:
            tau[j] = 0.0
            continue
        beta = -math.copysign(math.sqrt(alpha * alpha + xn), alpha)
        tau[j] = (beta - alpha) / beta
        scale = 1.0 / (alpha - beta)
        for i in range(j + 1, r):
            a[j, i] *= scale
        a[j, j] = beta
        for col in range(j + 1, m):
            s = a[col, j]
            for i in range(j + 1, r):
                s += a[j, i] * a[col, i]
            s *= tau[j]
            a[col, j] -= s
            for i in range(j + 1, r):
                a[col, i] -= s * a[j, i]
    return k


@njit(cache=True)
def _form_q(a, r, k, tau, Q, w):
    """Q (r, r) = H_0 ... H_{k-1} from the reflectors in a (``_pivoted_qr``), by backward accumulation."""
    for i in range(r):
        for j in range(r):
            Q[i, j] = 0.0
        Q[i, i] = 1.0
    for j in range(k - 1, -1, -1):
        t = tau[j]
        if t == 0.0:
            continue
        # Q[j:, j:] -= t v (v^T Q[j:, j:]), v = (1, a[j, j+1:]).
        for col in range(j, r):
            w[col] = t * Q[j, col]
        for i in range(j + 1, r):
            vi = a[j, i]
            for col in range(j, r):
                w[col] += t * vi * Q[i, col]
        for col in range(j, r):
            Q[j, col] -= w[col]
        for i in range(j + 1, r):
            vi = a[j, i]
            for col in range(j, r):
                Q[i, col] -= vi * w[col]


@njit(cache=True)
def _cholesky_solve(H, rhs, n):
    """Solve H y = rhs for symmetric positive definite H (n, n), reading and overwriting H's lower triangle;
    y overwrites rhs. Returns False when H is not positive definite (LAPACK ``dposv`` info != 0)."""
    for j in range(n):
        s = H[j, j]
        for p in range(j):
            s -= H[j, p] * H[j, p]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        H[j, j] = d
        for i in range(j + 1, n):
            s = H[i, j]
            for p in range(j):
                s -= H[i, p] * H[j, p]
            H[i, j] = s / d
    for i in range(n):
        s = rhs[i]
        for p in range(i):
            s -= H[i, p] * rhs[p]
        rhs[i] = s / H[i, i]
    for i in range(n - 1, -1, -1):
        s = rhs[i]
        for p in range(i + 1, n):
            s -= H[p, i] * rhs[p]
        rhs[i] = s / H[i, i]
    return True


@njit(cache=True)
def _split_lstsq(a, r, m, tau, piv, Q, tmp, c, eps, w, v0, y):
    """Rank and damped least squares of ``M z ~ c`` from the pivoted QR of ``M^T`` in a (m, r) (``_pivoted_qr``).

    Forms Q (r, r) and writes ``w`` (r,) = argmin ||M w - c||^2 + eps ||w||^2 on the revealed row space
    (``linalg.RowSpaceSplit.lstsq``). Returns the rank, or -1 when the normal equations are singular.
    """
    k = min(r, m)
    rank = 0
    if k > 0:
        top = abs(a[0, 0])
        if top > RANK_ATOL:
            for i in range(k):
                if abs(a[i, i]) > RANK_RTOL * top:
                    rank += 1
    _form_q(a, r, k, tau, Q, v0)
    for i in range(r):
        w[i] = 0.0
    if rank == 0:
        return 0
    if eps == 0.0 and rank == m:
        # Full row rank: R11^T y = P^T c exactly (forward substitution on the transposed triangle).
        for i in range(rank):
            s = c[piv[i]]
            for p in range(i):
                s -= a[i, p] * y[p]
            y[i] = s / a[i, i]
    else:
        # (R1 R1^T + eps I) y = R1 P^T c with R1 (rank, m) the upper trapezoid of R: R1[i, p] = a[p, i], p >= i.
        for i in range(rank):
            s = 0.0
            for p in range(i, m):
                s += a[p, i] * c[piv[p]]
            y[i] = s
            for j in range(i + 1):
                g = 0.0
                for p in range(i, m):  # R1[j, p] is zero for p < j <= i
                    g += a[p, i] * a[p, j]
                tmp[i, j] = g
            tmp[i, i] += eps
        if not _cholesky_solve(tmp, y, rank):
            return -1
    for i in range(r):
        s = 0.0
        for j in range(rank):
            s += Q[i, j] * y[j]
        w[i] = s
    return rank


@njit(cache=True)
def _damped_normal(M, m, r, c, eps, H, w):
    """w (r,) = (M^T M + eps I)^-1 M^T c for M (m, r), eps > 0; False when not positive definite."""
    for i in range(r):
        w[i] = 0.0
        for j in range(i + 1):
            H[i, j] = 0.0
    for p in range(m):
        cp = c[p]
        for i in range(r):
            mi = M[p, i]
            w[i] += mi * cp
            for j in range(i + 1):
                H[i, j] += mi * M[p, j]
    for i in range(r):
        H[i, i] += eps
    return _cholesky_solve(H, w, r)


@njit(cache=True)
def run_levels(A, b, offs, lb, ub, eps, G, h, W, I, resume):
    """Run the recursion from level ``state[ST_LEVEL]`` until done or a level needs its QP.

    Args:
        A: (sum m_k, n) every level's rows stacked; b: (sum m_k,); offs: (L + 1,) level row offsets.
        lb, ub: (n,) box [rad/s]. eps: (L,) per-level damping. G (p, n), h (p,): inequality rows (p may be 0).
        W, I: a :class:`Workspace`'s buffers (its state: level 0 and cols -1 to start).
        resume: the level ``state[ST_LEVEL]`` was solved by the caller's QP, its answer is in x: take it
            (the level's QR is still in the workspace) and go on with the next level.

    Returns:
        ``DONE`` (x holds the solution, res its residuals, ``state[ST_ACTIVE]`` its active bounds),
        ``NEEDS_QP`` (``state`` says the level, the Z columns (-1 = identity) and the rows; M, c and base
        hold that level's problem in its variables) or ``SINGULAR``.
    """
    n = lb.shape[0]
    L = offs.shape[0] - 1
    mm = (I.shape[0] - _ST_SIZE) if I.shape[0] > _ST_SIZE else 0
    state = I[:_ST_SIZE]
    piv = I[_ST_SIZE:]
    nv = max(n, mm)
    o = 0
    x = W[o : o + n]
    o += n
    base = W[o : o + n]
    o += n
    Z = W[o : o + n * n].reshape((n, n))
    o += n * n
    M = W[o : o + mm * n].reshape((mm, n))
    o += mm * n
    c = W[o : o + mm]
    o += mm
    res = W[o : o + L]
    o += L
    a = W[o : o + mm * n].reshape((mm, n))
    o += mm * n
    tau = W[o : o + n]
    o += n
    Q = W[o : o + n * n].reshape((n, n))
    o += n * n
    tmp = W[o : o + n * n].reshape((n, n))
    o += n * n
    v0 = W[o : o + nv]
    y = W[o + nv : o + 2 * nv]
    xt = W[o + 2 * nv : o + 3 * nv]
    w = W[o + 3 * nv : o + 4 * nv]
    p_rows = h.shape[0]
    k = state[ST_LEVEL]
    r = state[ST_COLS]
    if not resume:
        for i in range(n):
            x[i] = 0.0
    while k < L:
        last = k == L - 1
        if resume:
            resume = False
            rank = state[ST_RANK]
        else:
            if r == 0:
                break  # no freedom left for lower levels
            r0 = offs[k]
            m = offs[k + 1] - r0
            cols = n if r < 0 else r
            # base: the point of x + range(Z) nearest the box centre; M = A Z; c = b - A base.
            if r < 0:
                for i in range(n):
                    base[i] = 0.5 * (lb[i] + ub[i])
            else:
                for j in range(r):
                    w[j] = 0.0
                for i in range(n):
                    d = 0.5 * (lb[i] + ub[i]) - x[i]
                    for j in range(r):
                        w[j] += Z[i, j] * d
                for i in range(n):
                    s = x[i]
                    for j in range(r):
                        s += Z[i, j] * w[j]
                    base[i] = s
            for p in range(m):
                s = b[r0 + p]
                for i in range(n):
                    s -= A[r0 + p, i] * base[i]
                c[p] = s
                if r < 0:
                    for i in range(n):
                        M[p, i] = A[r0 + p, i]
                else:
                    for j in range(r):
                        M[p, j] = 0.0
                    for i in range(n):
                        api = A[r0 + p, i]
                        for j in range(r):
                            M[p, j] += api * Z[i, j]
            e = eps[k]
            if last and e > 0.0:
                rank = -2  # no split on the last level: its damped normal equations
                if not _damped_normal(M, m, cols, c, e, tmp, w):
                    state[ST_STATUS] = SINGULAR
                    return SINGULAR
            else:
                for p in range(m):
                    for i in range(cols):
                        a[p, i] = M[p, i]
                _pivoted_qr(a, cols, m, tau, piv, v0)
                rank = _split_lstsq(a, cols, m, tau, piv, Q, tmp, c, e, w, v0, y)
                if rank < 0:
                    state[ST_STATUS] = SINGULAR
                    return SINGULAR
            # The unconstrained damped optimum, taken when it is inside the box and meets every row.
            ok = True
            for i in range(n):
                s = base[i]
                if r < 0:
                    s += w[i]
                else:
                    for j in range(r):
                        s += Z[i, j] * w[j]
                xt[i] = s
                if s < lb[i] - FEASIBLE_TOL or s > ub[i] + FEASIBLE_TOL:
                    ok = False
            if ok:
                for q in range(p_rows):
                    s = 0.0
                    for i in range(n):
                        s += G[q, i] * xt[i]
                    if s > h[q] + FEASIBLE_TOL:
                        ok = False
                        break
            if not ok:
                state[ST_LEVEL] = k
                state[ST_COLS] = r
                state[ST_RANK] = rank
                state[ST_ROWS] = m
                state[ST_STATUS] = NEEDS_QP
                return NEEDS_QP
            for i in range(n):
                x[i] = xt[i]
        if last:
            break
        # Z <- Z N with N = Q[:, rank:] the null space of this level's M.
        cols = n if r < 0 else r
        nr = cols - rank
        if r < 0:
            for i in range(n):
                for j in range(nr):
                    Z[i, j] = Q[i, rank + j]
        else:
            for i in range(n):
                for j in range(nr):
                    tmp[i, j] = 0.0
                for p in range(cols):
                    zp = Z[i, p]
                    for j in range(nr):
                        tmp[i, j] += zp * Q[p, rank + j]
            for i in range(n):
                for j in range(nr):
                    Z[i, j] = tmp[i, j]
        r = nr
        k += 1
    # Every level's residual ||A_k x - b_k|| and the active bounds (base.level_residuals, base.count_active).
    for kk in range(L):
        t = 0.0
        for p in range(offs[kk], offs[kk + 1]):
            s = -b[p]
            for i in range(n):
                s += A[p, i] * x[i]
            t += s * s
        res[kk] = math.sqrt(t)
    active = 0
    for i in range(n):
        if x[i] <= lb[i] + 1e-9 or x[i] >= ub[i] - 1e-9:
            active += 1
    state[ST_LEVEL] = k
    state[ST_COLS] = r
    state[ST_ACTIVE] = active
    state[ST_STATUS] = DONE
    return DONE


_warm = False


def warm_up() -> None:
    """Compile (or load from the cache) the kernel on a tiny problem, once a process: call it before any
    real-time tick (``HqpNullspace`` does when built)."""
    global _warm
    if _warm:
        return
    A = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
    b = np.array([0.1, 0.2])
    offs = np.array([0, 1, 2], dtype=np.int64)
    ws = Workspace(3, 3, 2)
    ws.state[ST_COLS] = -1
    run_levels(A, b, offs, -np.ones(3), np.ones(3), np.full(2, 1e-6), np.zeros((0, 1)), np.zeros(0), ws.W, ws.I, False)
    _warm = True


if __name__ == "__main__":
    # `python -m services.solver.hqp_kernel`: compile into the cache ahead of time (make setup, the image build).
    warm_up()
