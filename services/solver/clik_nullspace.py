"""CLIK with a null-space secondary objective (seed 004, eqs. 2-6).

    qd = J1^+ (xd_dot + K e1) + (I - J1^+ J1) qd0,     qd0 = -eta grad H(q)

Level 1 (the wrists) gives ``J1 = A_1`` and ``xd_dot + K e1 = b_1``. Seed 004
takes H as the orientation error of the upper-arm link; here H is the
objective of every lower level at qd = 0, ``H = 1/2 sum_k ||A_k qd - b_k||^2``,
whose negative gradient is ``sum_k A_k^T b_k``: for the elbow level that is
``J_elbow^T W^2 (v_ff + K e_elbow)``, the elbow position error pulled through
the arm's self-motion. The pseudo-inverse and the projector come from the same
rank-revealing QR as HQP-Nullspace.

Limits are NOT part of the solve: the result is clamped into the velocity
bounds afterwards, which keeps the robot within its limits but can break the
wrist task whenever a clamp is active (that is the method's known weakness).
"""

from __future__ import annotations

from services.solver.base import Algorithm, LevelProblem, Solution
from services.solver.linalg import split_row_space


class ClikNullspace(Algorithm):
    """Pseudo-inverse CLIK on level 1 plus projected gradient of the lower levels, then clamping.

    Args:
        eta: step size of the secondary gradient (dimensionless, on A^T b).
        damping: damping of the pseudo-inverse (0 = the plain Moore-Penrose one of eq. 2).
    """

    name = "clik-nullspace"

    def __init__(self, eta: float = 1.0, damping: float = 0.0):
        super().__init__()
        if eta < 0:
            raise ValueError(f"eta must be >= 0, got {eta}")
        self.eta = eta
        self.damping = damping

    def solve_problem(self, p: LevelProblem) -> Solution:
        # p.ineq: a clamping baseline cannot honour inequality rows (the method's weakness); ignored.
        As, bs = p.As, p.bs
        split = split_row_space(As[0])
        qd = split.lstsq(bs[0], self.damping)
        if len(As) > 1 and self.eta > 0:
            qd0 = sum(A.T @ b for A, b in zip(As[1:], bs[1:]))
            N = split.null_basis
            qd = qd + self.eta * (N @ (N.T @ qd0))
        return p.clamped(qd)
