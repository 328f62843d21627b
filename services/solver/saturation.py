"""Saturated wrists: the wrist task velocity a tick aims at when the wrists cannot be met within the joint box.

Why (issue 12, the vigorous clips; ``mimic eval --no-sim``): a running operator's hands move at 1-3.4 m/s, beyond
what the G1's joints gave the wrists at the 4 rad/s cap of the time, so level 1 could not be met on 60-80 % of the
ticks of dash_active, dash_proud and run_happy. The strict hierarchy then keeps level 1's least-squares optimum, a
vertex of the box with 9-10 of the 17 joints at a velocity bound (the wrist joints too: they spin at full speed for
the few cm/s their 4.6 cm lever gives the wrist frame): the set of equally good velocities is a point, the elbows
get nothing, and the posture drifts wherever the greedy wrist steps take it (run_happy's elbows 11 cm off even on
the ticks the wrists are met, against 3.9 cm for the weighted QP and 3.7 cm for mink).

What this does instead, only on those ticks: the wrist level and the levels below are traded in one weighted QP
(``WeightedQp``, wrist rows weighted ``weight`` against 1 for every lower level), with the wrist level's loss
capped: its residual may be at most ``(1 + tolerance)`` times the strict optimum's ``r1*``. When the weighted
optimum gives up more, the wrist weight is raised (bisection on its logarithm) until the cap holds. The wrist
task velocity of that solution is then the demand the strict hierarchy meets exactly, so every lower level is
optimised, strictly in order, inside the set of velocities that give the wrists exactly that (at least as good
for them as the weighted solution itself). A tick whose wrist level can be met is never traded: the hierarchy is
strict there, level 2 cannot change level 1.

The cap keeps the wrists moving towards a target the arm can reach: whenever ``(1 + tolerance) r1* < |b1|`` the
traded wrist velocity still has a component along the demand. Without it (the weighted trade alone) the elbow held
kick_normal's right wrist 6-12 cm off a reachable, nearly still target for 5.4 s.
"""

from __future__ import annotations

import math

import numpy as np

from services.solver.base import LevelProblem
from services.solver.qp import QpBackend
from services.solver.wqp import WeightedQp

#: Largest wrist weight the bisection tries: at 1e4 against 1 the trade is the strict optimum to within round-off.
MAX_WEIGHT = 1e4
#: Bisection steps on log10(weight) when the weighted optimum breaks the cap (each one weighted QP).
BISECTION_STEPS = 6


class SaturatedWristTrade:
    """The wrist task velocity to aim at on a tick whose wrist level cannot be met.

    Args:
        backend: QP backend of the weighted problem.
        weight: the wrist level's weight against 1 for each lower level (``WeightedQp``'s level weights, squared in
            the objective), > 0.
        tolerance: the wrist residual may grow to ``(1 + tolerance)`` times the strict optimum's, >= 0.
        damping: Tikhonov damping of the weighted problem.
    """

    def __init__(self, backend: QpBackend, weight: float, tolerance: float, damping: float = 1e-6):
        if not weight > 0.0:
            raise ValueError(f"saturation weight must be > 0, got {weight}")
        if not tolerance >= 0.0:
            raise ValueError(f"saturation tolerance must be >= 0, got {tolerance}")
        self.weight = float(weight)
        self.tolerance = float(tolerance)
        self.wqp = WeightedQp(backend, (self.weight, 1.0), eps=damping)
        #: ticks traded, and of those the ones whose cap needed the bisection (since built)
        self.counts = {"traded": 0, "capped": 0}

    def wrist_velocity(self, p: LevelProblem, r1: float) -> np.ndarray | None:
        """The level-1 task velocity ``A_1 x`` (m_1,) to aim at, or None (keep the strict solution).

        Args:
            p: the levels (level 0: the wrists) and the box of this tick.
            r1: the strict optimum's level-1 residual ``||A_1 x* - b_1||`` (> the feasibility tolerance).

        Returns:
            ``A_1 x`` of the weighted optimum whose level-1 residual is at most ``(1 + tolerance) r1``: at ``weight``
            when that holds, else at the smallest weight the bisection finds that keeps it; None when no weight up to
            ``MAX_WEIGHT`` does or the QPs fail.
        """
        cap = (1.0 + self.tolerance) * r1
        x = self._solve(p, self.weight)
        if x is not None and self._residual(p, x) <= cap:
            self.counts["traded"] += 1
            return p.As[0] @ x
        lo, hi = math.log10(self.weight), math.log10(MAX_WEIGHT)
        best = None
        for _ in range(BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            x = self._solve(p, 10.0**mid)
            if x is not None and self._residual(p, x) <= cap:
                best, hi = x, mid
            else:
                lo = mid
        if best is None:
            return None
        self.counts["traded"] += 1
        self.counts["capped"] += 1
        return p.As[0] @ best

    def _solve(self, p: LevelProblem, weight: float) -> np.ndarray | None:
        """The weighted optimum (n,) [rad/s] with the wrist level at ``weight``, or None when its QP failed."""
        self.wqp.level_weights = (weight, 1.0)
        sol = self.wqp.solve_problem(LevelProblem(p.As, p.bs, p.lb, p.ub, p.ineq))
        return sol.qd if sol.ok else None

    @staticmethod
    def _residual(p: LevelProblem, x: np.ndarray) -> float:
        r = p.As[0] @ x - p.bs[0]
        return math.sqrt(float(r @ r))
