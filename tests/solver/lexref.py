"""Brute-force lexicographic reference for two-level box-constrained least squares.

Independent of the solver code: it enumerates every assignment of each variable
to {free, at lower bound, at upper bound}, solves the unconstrained
lexicographic problem on the free variables with NumPy's SVD least squares,
keeps the candidates that respect the bounds and returns the lexicographic
minimum of their residuals. Some optimum has free variables whose
lexicographic problem has a unique solution (move along the remaining null
space until a bound becomes active, fix it, repeat), so the enumeration finds
the optimum's residuals exactly.
"""

from __future__ import annotations

import itertools

import numpy as np


def _lstsq_null(M: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u, s, vt = np.linalg.svd(M, full_matrices=True)
    tol = max(M.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0)
    rank = int(np.count_nonzero(s > max(tol, 1e-12)))
    y = vt[:rank].T @ ((u[:, :rank].T @ c) / s[:rank])
    return y, vt[rank:].T


def lexicographic_reference(A1, b1, A2, b2, lb, ub, tol: float = 1e-9) -> tuple[float, float]:
    """(level-1 residual, level-2 residual) of the exact lexicographic optimum."""
    n = lb.shape[0]
    best: list[tuple[float, float]] = []
    for pattern in itertools.product((0, 1, 2), repeat=n):
        pat = np.array(pattern)
        free = pat == 0
        x = np.where(pat == 1, lb, np.where(pat == 2, ub, 0.0))
        if free.any():
            F = np.flatnonzero(free)
            c1 = b1 - A1 @ x
            y1, N1 = _lstsq_null(A1[:, F], c1)
            y = y1
            if N1.shape[1]:
                c2 = b2 - A2 @ x - A2[:, F] @ y1
                w, _ = _lstsq_null(A2[:, F] @ N1, c2)
                y = y1 + N1 @ w
            x[F] = y
            if np.any(x < lb - tol) or np.any(x > ub + tol):
                continue
        best.append((float(np.linalg.norm(A1 @ x - b1)), float(np.linalg.norm(A2 @ x - b2))))
    r1 = min(r for r, _ in best)
    r2 = min(s for r, s in best if r <= r1 + 1e-9 * (1.0 + r1))
    return r1, r2
