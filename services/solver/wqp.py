"""Weighted QP (the "traditional QP" of seed 000): every level in one objective.

    min sum_k w_k^2 ||A_k x - b_k||^2 + eps ||x||^2    s.t.  lb <= x <= ub

Priorities are only as strict as the weights make them: a lower level can pull
a higher one off its target, which is what the HQPs are compared against.

Same tasks, gains, limits and damping as the HQPs (the levels SolverCore builds);
only the priority is soft. Level weights (1.0, 0.3, 1.0), squared in the objective:

* level 1, wrists (1.0): the main objective, as in the paper's "traditional QP";
* level 2, elbows (0.3): present but subordinate, so they bend to the wrists; with
  elbow targets the robot can reach together with its wrist targets (retarget
  ``elbow_placement="swivel"``) the weight rarely matters, with the paper's per-axis
  mapped elbows it sets how far the elbow error trades against the wrist's;
* level 3 (1.0 x each task's own cost): posture (cost 1e-2) and, with
  ``wrist_orientation_level=3``, the wrist orientations (cost 0.045).

The seed does not give its weights; its WQP elbow error (5.58 cm mean) is what an
elbow that is nearly ignored gives, so this WQP is the stronger of the two.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.linalg import lapack

from services.solver.base import QP_BOUND_TOL, LevelProblem, Solution, clip, within
from services.solver.cascade import CascadeQp
from services.solver.inequalities import NO_BOUND
from services.solver.qp import QpBackend


class WeightedQp(CascadeQp):
    """One weighted QP over all levels.

    Args:
        backend: QP backend.
        level_weights: w_k per level (missing levels reuse the last weight).
        eps: Tikhonov regularisation (one objective: the first level's damping is used).
        shortcut: use the unconstrained optimum when it respects the bounds.
    """

    name = "wqp"

    def __init__(
        self,
        backend: QpBackend,
        level_weights: Sequence[float] = (1.0, 0.3, 1.0),
        eps: float | Sequence[float] = 1e-9,
        shortcut: bool = True,
    ):
        super().__init__(backend, eps, refine=False)
        if not level_weights or any(w <= 0 for w in level_weights):
            raise ValueError(f"level weights must be > 0, got {level_weights}")
        self.level_weights = tuple(float(w) for w in level_weights)
        self.shortcut = shortcut

    def solve_problem(self, p: LevelProblem) -> Solution:
        lb, ub, ineq, n = p.lb, p.ub, p.ineq, p.n
        rows = ineq is not None
        H = np.zeros((n, n))
        f = np.zeros(n)
        for k, (A, b) in enumerate(zip(p.As, p.bs)):
            w2 = self.level_weights[min(k, len(self.level_weights) - 1)] ** 2
            H += w2 * (A.T @ A)
            f -= w2 * (A.T @ b)
        H.flat[:: n + 1] += self.level_eps(0)
        if self.shortcut:
            _c, x, info = lapack.dposv(H, -f)
            if info == 0 and within(x, lb, ub) and (not rows or ineq.satisfied(x)):
                return p.solution(x)
        if rows:
            low = np.full(ineq.rows, NO_BOUND)
            r = self.backend.solve(H, f, lb=lb, ub=ub, G=ineq.G, gl=low, gu=ineq.h, key="wqpg")
        else:
            r = self.backend.solve(H, f, lb=lb, ub=ub, key="wqp")
        if not r.ok or not within(r.x, lb, ub, QP_BOUND_TOL) or (rows and not ineq.satisfied(r.x, QP_BOUND_TOL)):
            why = r.status if not r.ok else "QP left the box"
            return p.solution(np.zeros(n), False, r.iters, 1, f"QP: {why}")
        return p.solution(clip(r.x, lb, ub), True, r.iters, 1)
