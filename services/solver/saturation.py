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
optimum gives up more, the aim moves back along the segment from its wrist velocity to the strict optimum's until
the cap holds. That wrist task velocity is then the demand the strict hierarchy meets exactly, so every lower level
is optimised, strictly in order, inside the set of velocities that give the wrists exactly that (at least as good
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
        #: ticks traded, and of those the ones held to the cap (since built)
        self.counts = {"traded": 0, "capped": 0}

    def wrist_velocity(self, p: LevelProblem, strict_qd: np.ndarray) -> np.ndarray | None:
        """The level-1 task velocity (m_1,) to aim at, or None (keep the strict solution).

        Args:
            p: the levels (level 0: the wrists) and the box of this tick.
            strict_qd: (n,) [rad/s] the strict optimum ``x*``, whose level-1 residual ``r1* = ||A_1 x* - b_1||`` is
                above the feasibility tolerance.

        Returns:
            ``A_1 x_w`` of the weighted optimum ``x_w`` when its level-1 residual is at most ``(1 + tolerance) r1*``;
            else the point of the segment from ``A_1 x*`` to ``A_1 x_w`` furthest along it whose residual is exactly
            that cap (capped). Every point of the segment is ``A_1`` of a velocity between ``x*`` and ``x_w``, both
            within the box and the rows, so the strict hierarchy can meet it. None when the weighted QP fails.
        """
        weighted = self.wqp.solve_problem(p)
        if not weighted.ok:
            return None
        a_s = p.As[0] @ strict_qd
        r = a_s - p.bs[0]
        rr = float(r @ r)
        cap2 = (1.0 + self.tolerance) ** 2 * rr
        a_w = p.As[0] @ weighted.qd
        self.counts["traded"] += 1
        d = a_w - a_s
        rw = r + d
        if float(rw @ rw) <= cap2:
            return a_w
        # Capped: the largest t in (0, 1) with ||r + t d||^2 = cap^2 (one root is positive: ||r||^2 < cap^2); the
        # residual is convex along the segment, so every point up to t keeps the cap. The bisection of the weight used
        # before (up to 6 more weighted QPs a tick) took the vigorous clips' tick p95 to 1.31 ms, against 0.87 now.
        dd, rd = float(d @ d), float(r @ d)
        t = (-rd + math.sqrt(max(rd * rd - dd * (rr - cap2), 0.0))) / dd
        self.counts["capped"] += 1
        return a_s + min(t, 1.0) * d
