"""Refining a QP solution on its active set: the exact optimum an interior-point answer only approaches.

Interior-point solvers stop at a tolerance, and a least-squares objective
accurate to 1e-10 only pins the task value to about 1e-5. With the active set
read off the QP solution, the exact optimum is an equality-constrained least
squares, solved by a null-space step and accepted only when it stays in the box
and does not raise the objective.
"""

from __future__ import annotations

import numpy as np

from services.solver.base import FEASIBLE_TOL
from services.solver.linalg import split_row_space

#: Relative tolerance on equality rows ``||C z - d|| <= EQ_RTOL (1 + ||d||)``.
EQ_RTOL = 1e-9


def refine_on_active_set(
    M: np.ndarray,
    c: np.ndarray,
    z: np.ndarray,
    G: np.ndarray | None,
    lo: np.ndarray,
    hi: np.ndarray,
    E: np.ndarray | None = None,
    e: np.ndarray | None = None,
    eps: float = 0.0,
    act_tol: float = 1e-5,
) -> np.ndarray:
    """Refine a QP solution of ``min ||M z - c||^2 + eps ||z||^2`` s.t. ``lo <= G z <= hi``, ``E z = e``.

    Args:
        M: (m, r), c: (m,), z: (r,) QP solution. G: (p, r) rows bounded by lo, hi (p,); None = identity.
        E, e: optional equality rows (q, r) and values (q,).
        eps: the QP's Tikhonov weight (kept in the refined problem).
        act_tol: distance to a bound under which a row counts as active.

    Returns:
        the refined z (r,), or z itself when the refinement would leave the box or do worse.
    """
    C, d = _active_rows(z, G, lo, hi, E, e, act_tol)
    if C is not None:
        split = split_row_space(C)
        z0 = split.lstsq(d)
        if not _meets(C, z0, d):
            return z
        N = split.null_basis
    else:
        z0 = np.zeros_like(z)
        N = np.eye(z.shape[0])
    zp = z0 + N @ _free_step(M, c, z0, N, eps) if N.shape[1] else z0
    gp = zp if G is None else G @ zp
    if ((gp < lo - FEASIBLE_TOL) | (gp > hi + FEASIBLE_TOL)).any():
        return z
    if E is not None and not _meets(E, zp, e):
        return z
    if _objective(M, c, eps, zp) > _objective(M, c, eps, z) + 1e-12:
        return z
    return zp


def _active_rows(z, G, lo, hi, E, e, act_tol):
    """Equality rows (C, d) of the active set: E z = e plus every bound row within act_tol (None: none)."""
    g = z if G is None else G @ z
    at_lo = g <= lo + act_tol
    at_hi = g >= hi - act_tol
    act = at_lo | at_hi
    rows = [] if E is None else [E]
    vals = [] if E is None else [e]
    if act.any():
        rows.append(np.eye(z.shape[0])[act] if G is None else G[act])
        vals.append(np.where(at_lo, lo, hi)[act])
    if not rows:
        return None, None
    return np.vstack(rows), np.concatenate(vals)


def _free_step(M, c, z0, N, eps):
    """w minimising ``||M (z0 + N w) - c||^2 + eps ||z0 + N w||^2`` for an orthonormal N."""
    MN = M @ N
    rhs = c - M @ z0
    if not eps:
        return split_row_space(MN).lstsq(rhs)
    H = MN.T @ MN
    H.flat[:: H.shape[0] + 1] += eps
    return np.linalg.solve(H, MN.T @ rhs - eps * (N.T @ z0))


def _meets(C: np.ndarray, z: np.ndarray, d: np.ndarray) -> bool:
    return bool(np.linalg.norm(C @ z - d) <= EQ_RTOL * (1.0 + np.linalg.norm(d)))


def _objective(M: np.ndarray, c: np.ndarray, eps: float, x: np.ndarray) -> float:
    r = M @ x - c
    return float(r @ r + eps * (x @ x))
