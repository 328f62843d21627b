"""Small dense linear algebra for the solvers: rank-revealing QR, least squares, null spaces.

Column-pivoted Householder QR (LAPACK ``dgeqp3`` + ``dorgqr`` through SciPy)
is used instead of an SVD: on the 12 x 17 wrist level it takes about 14 us
against about 40 us for ``dgesdd`` on this machine, and it reveals the rank
just as well for the null-space bases the hierarchy needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

#: Relative threshold on |R_ii| / |R_00| below which a pivot counts as zero.
RANK_RTOL = 1e-9
#: Absolute threshold: a matrix whose largest pivot is below it has rank 0.
RANK_ATOL = 1e-12


@dataclass(slots=True)
class RowSpaceSplit:
    """Column-pivoted QR of M^T for M (m, r): ``M^T P = Q R``.

    Attributes:
        rank: numerical rank rho.
        Q: (r, r) orthogonal; ``Q[:, :rank]`` spans the row space of M,
            ``Q[:, rank:]`` its null space.
        R: (k, m) whose upper trapezoid is R, k = min(r, m) (below the diagonal: LAPACK reflectors).
        piv: (m,) 0-based pivot order of the rows of M.
    """

    rank: int
    Q: np.ndarray
    R: np.ndarray
    piv: np.ndarray

    @property
    def null_basis(self) -> np.ndarray:
        """(r, r - rank) orthonormal basis of null(M)."""
        return self.Q[:, self.rank :]

    def lstsq(self, c: np.ndarray, damping: float = 0.0) -> np.ndarray:
        """Least-squares solution z (r,) of ``M z ~ c`` for c (m,).

        With ``damping`` = 0 the minimum-norm solution; otherwise the damped one,
        ``argmin ||M z - c||^2 + damping ||z||^2``, which keeps velocities finite
        near singular configurations. Only the rank-revealed row space is used.
        """
        rho = self.rank
        r = self.Q.shape[0]
        if rho == 0:
            return np.zeros(r)
        cp = c[self.piv]
        if damping == 0.0 and rho == cp.shape[0]:
            # Full row rank: R11^T y = P^T c exactly (zero residual). dtrtrs reads the upper triangle only.
            y, _info = lapack.dtrtrs(self.R[:rho, :rho], cp, lower=0, trans=1)
        else:
            # M^T M = Q R R^T Q^T on the row space: normal equations of the small (rho, rho) system.
            R1 = self.R[:rho] * _upper_mask(rho, cp.shape[0])
            G = R1 @ R1.T
            if damping:
                G.flat[:: rho + 1] += damping
            _c, y, info = lapack.dposv(G, R1 @ cp)
            if info != 0:
                raise np.linalg.LinAlgError(f"dposv failed with info={info}")
        return self.Q[:, :rho] @ y


def split_row_space(M: np.ndarray) -> RowSpaceSplit:
    """Rank-revealing split of the row space and null space of M (m, r)."""
    m, r = M.shape
    if m == 0 or r == 0:
        return RowSpaceSplit(0, np.eye(r), np.zeros((0, m)), np.arange(m))
    qr, jpvt, tau, _work, info = lapack.dgeqp3(np.asfortranarray(M.T))
    if info != 0:
        raise np.linalg.LinAlgError(f"dgeqp3 failed with info={info}")
    k = min(r, m)
    d = np.abs(np.diagonal(qr)[:k])
    top = d[0] if k else 0.0
    rank = 0 if top <= RANK_ATOL else int(np.count_nonzero(d > RANK_RTOL * top))
    a = np.zeros((r, r), order="F")
    a[:, :k] = qr[:, :k]
    Q, _work, info = lapack.dorgqr(a, tau[:k], overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"dorgqr failed with info={info}")
    return RowSpaceSplit(rank, Q, qr[:k], jpvt - 1)


_MASKS: dict[tuple[int, int], np.ndarray] = {}


def _upper_mask(rows: int, cols: int) -> np.ndarray:
    mask = _MASKS.get((rows, cols))
    if mask is None:
        mask = _MASKS[(rows, cols)] = np.triu(np.ones((rows, cols)))
    return mask
