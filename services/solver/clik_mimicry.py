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

from services.solver.base import Algorithm, LevelProblem, Solution
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

    def solve_problem(self, p: LevelProblem) -> Solution:
        # p.ineq: a clamping method cannot honour inequality rows (as clik-nullspace); ignored.
        if p.levels is not None:
            # Solved from the tasks: q̇₀ from each lower task as the module doc says (exact alignment gradient).
            qd0 = secondary_velocity(p.configuration, [t for tasks in p.levels[1:] for t in tasks], self.eta)
        else:
            # Only the rows are known: every lower level contributes Aᵀ b.
            qd0 = np.zeros(p.n)
            for A, b in zip(p.As[1:], p.bs[1:]):
                qd0 += A.T @ b
        return p.clamped(clik_step(p.As[0], p.bs[0], qd0, self.damping))
