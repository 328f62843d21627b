"""Damped least squares IK (seed 003, section 1.2): Newton iterations at position level.

Only the first level (the wrist poses) is used, as the simple baseline:

    q <- q + (J^T W J + lambda I)^-1 J^T W e(q)       (a few iterations per tick)

with ``e`` the pose error towards the target advanced by its velocity over dt.
Each iterate is clipped into the box reachable in one step from the current q
(position limits and vmax dt), and the joint velocity is ``(q_new - q) / dt``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.linalg import lapack

from services.solver.algorithm import Algorithm, Solution, count_active, level_residuals
from shared.kinematics import Configuration, Limit, Task


class DampedLeastSquares(Algorithm):
    """Position-level DLS on the level-1 tasks.

    Args:
        damping: lambda, Levenberg-Marquardt damping.
        iterations: Newton iterations per tick.
    """

    name = "dls"

    def __init__(self, damping: float = 1e-3, iterations: int = 3):
        super().__init__()
        if damping <= 0 or iterations < 1:
            raise ValueError("damping must be > 0 and iterations >= 1")
        self.damping = damping
        self.iterations = iterations

    def solve(
        self,
        configuration: Configuration,
        levels: Sequence[Sequence[Task]],
        limits: Sequence[Limit],
        dt: float,
    ) -> Solution:
        if not levels or not levels[0]:
            raise ValueError("at least one level with one task is needed")
        As, bs = self.stack(levels, configuration.nv).fill(configuration)
        lb, ub = self.bounds(limits, configuration, dt)
        q0 = configuration.q.copy()
        lo, hi = q0 + lb * dt, q0 + ub * dt
        tasks = levels[0]
        m = sum(t.dim for t in tasks)
        J = np.empty((m, configuration.nv))
        e = np.empty(m)
        q = q0.copy()
        try:
            for it in range(self.iterations):
                if it:
                    configuration.update(q)
                i = 0
                for t in tasks:
                    w = t.cost
                    J[i : i + t.dim] = w[:, None] * t.compute_jacobian(configuration)
                    e[i : i + t.dim] = w * (t.compute_error(configuration) + t.feedforward() * dt)
                    i += t.dim
                H = J.T @ J
                H.flat[:: H.shape[0] + 1] += self.damping
                _c, step, info = lapack.dposv(H, J.T @ e)
                if info != 0 or not np.all(np.isfinite(step)):
                    return Solution(np.zeros_like(q0), level_residuals(As, bs, 0 * q0), False, it, 0, 0, "DLS step")
                np.clip(q + step, lo, hi, out=q)
        finally:
            configuration.update(q0)
        qd = np.clip((q - q0) / dt, lb, ub)
        return Solution(qd, level_residuals(As, bs, qd), True, self.iterations, 0, count_active(qd, lb, ub))

    def solve_matrices(self, As, bs, lb, ub):
        raise NotImplementedError("DLS iterates on the kinematics; call solve(configuration, levels, limits, dt)")
