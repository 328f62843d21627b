"""Seed 004's posture-mimicry CLIK (eqs. 2-6), as published.

    q̇ = J⁺(q) [ẋ_d + K_p (x_d - x)] + (I - J⁺(q) J(q)) q̇₀,        q̇₀ = -η ∇H(q)

Level 1 is the end-effector task (``J = A_1``, ``ẋ_d + K_p e = b_1``; the solver core puts
the full wrist poses there for this algorithm, as the paper does). The secondary velocity
``q̇₀`` comes from the lower levels:

- an :class:`~shared.kinematics.AlignmentTask` (the robot's upper-arm link against the
  operator's upper arm, eqs. 3-6) contributes ``-η ∇H(q)`` with the exact gradient;
- a :class:`~shared.kinematics.JointVelocityTask` contributes its velocities as they are
  (that is how a learned policy's ``q̇₀`` enters, seed 004 section 3);
- any other task contributes ``Aᵀ b``, the negative gradient of ``½||A q̇ - b||²`` at q̇ = 0
  (the same convention as ``clik-nullspace``).

``J⁺`` and the projector come from one rank-revealing QR (:mod:`.linalg`). As in the paper,
the limits are not part of the solve: the result is clamped into the velocity bounds, which
keeps the robot safe but can break the end-effector task while a clamp is active.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from services.solver.base import Algorithm, Solution, count_active, level_residuals
from services.solver.inequalities import Inequalities
from services.solver.linalg import split_row_space
from shared.kinematics import AlignmentTask, Configuration, JointVelocityTask, Task

#: Default η of eq. (3) [1/s]: near alignment the upper arm turns at about 2η times its error.
DEFAULT_ETA = 10.0


def clik_step(J: np.ndarray, b: np.ndarray, qd0: np.ndarray, damping: float = 0.0) -> np.ndarray:
    """Eq. (2): ``J⁺ b + (I - J⁺J) q̇₀`` (n,) for J (m, n), b (m,), q̇₀ (n,)."""
    split = split_row_space(J)
    qd = split.lstsq(b, damping)
    N = split.null_basis
    if N.shape[1]:
        qd = qd + N @ (N.T @ qd0)
    return qd


def secondary_velocity(configuration: Configuration, tasks: Sequence[Task], eta: float) -> np.ndarray:
    """q̇₀ (n,) [rad/s] of the lower-level tasks (see the module doc)."""
    qd0 = np.zeros(configuration.nv)
    for task in tasks:
        if isinstance(task, AlignmentTask):
            qd0 -= eta * task.gradient(configuration)
        elif isinstance(task, JointVelocityTask):
            qd0[task.joints] += task.cost * task.feedforward()
        else:
            A, b = task.compute_qp_objective(configuration)
            qd0 += A.T @ b
    return qd0


class ClikMimicry(Algorithm):
    """Pseudo-inverse CLIK on level 1 plus the null-space mimicry velocity, then clamping.

    Args:
        eta: η of eq. (3) [1/s].
        damping: damping of the pseudo-inverse (0 = the Moore-Penrose one of eq. 2).
    """

    name = "clik-mimicry"

    def __init__(self, eta: float = DEFAULT_ETA, damping: float = 0.0):
        super().__init__()
        if not eta >= 0:
            raise ValueError(f"eta must be >= 0, got {eta}")
        self.eta = eta
        self.damping = damping

    def solve(
        self,
        configuration: Configuration,
        levels: Sequence[Sequence[Task]],
        lb: np.ndarray,
        ub: np.ndarray,
        ineq: Inequalities | None = None,
    ) -> Solution:
        # ineq: a clamping method cannot honour inequality rows (as clik-nullspace); ignored.
        if not levels or not levels[0]:
            raise ValueError("at least one level with one task is needed")
        As, bs = self.stack(levels, configuration.nv).fill(configuration)
        qd0 = secondary_velocity(configuration, [t for tasks in levels[1:] for t in tasks], self.eta)
        return self._finish(clik_step(As[0], bs[0], qd0, self.damping), As, bs, lb, ub)

    def solve_matrices(
        self, As: Sequence[np.ndarray], bs: Sequence[np.ndarray], lb: np.ndarray, ub: np.ndarray, ineq=None
    ):
        qd0 = np.zeros(As[0].shape[1])
        for A, b in zip(As[1:], bs[1:]):
            qd0 += A.T @ b
        return self._finish(clik_step(As[0], bs[0], qd0, self.damping), As, bs, lb, ub)

    @staticmethod
    def _finish(qd, As, bs, lb, ub) -> Solution:
        clamped = np.minimum(np.maximum(qd, lb), ub)
        n_clamped = int(np.count_nonzero(clamped != qd))
        reason = f"clamped {n_clamped} joints" if n_clamped else ""
        return Solution(clamped, level_residuals(As, bs, clamped), True, 0, 0, count_active(clamped, lb, ub), reason)
