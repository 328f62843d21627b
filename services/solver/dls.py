"""Damped least squares (seed 003, section 1.2) on the first level, the simple baseline.

    qd = (A_1^T A_1 + lambda I)^-1 A_1^T b_1,      then clipped into the joint bounds

with ``A_1 = W J`` and ``b_1 = W (v_ff + gain e)`` the level-1 rows (the wrists)
as every algorithm gets them: the configured gain, the target velocity fed
forward. Lower levels are ignored (their residuals are still reported), and the
limits only clip the result, so a clipped joint costs the wrists accuracy: both
are the method's known weaknesses against the HQP.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from services.solver.base import Algorithm, LevelProblem, Solution


class DampedLeastSquares(Algorithm):
    """Velocity-level DLS on the level-1 rows, clipped into the bounds.

    Args:
        damping: lambda > 0, Levenberg-Marquardt damping [(rad/s)^-2 in the rows' units].
    """

    name = "dls"

    def __init__(self, damping: float = 1e-6):
        super().__init__()
        if not damping > 0:
            raise ValueError(f"damping must be > 0, got {damping}")
        self.damping = damping

    def solve_problem(self, p: LevelProblem) -> Solution:
        # p.ineq: a clamping baseline cannot honour inequality rows (the method's weakness); ignored.
        A, b = p.As[0], p.bs[0]
        H = A.T @ A
        H.flat[:: H.shape[0] + 1] += self.damping
        _c, qd, info = lapack.dposv(H, A.T @ b)
        if info != 0 or not np.all(np.isfinite(qd)):
            return p.solution(np.zeros(p.n), False, reason=f"DLS: dposv info {info}")
        return p.clamped(qd)
