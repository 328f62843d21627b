"""General inequality rows ``G qd <= h`` next to the joint box, hard at every priority level.

The joint limits are a box (``bounds.JointBounds``); constraints that couple joints, such as
the self-collision velocity dampers (``collision.SelfCollisionAvoidance``), are rows ``G qd <= h``
(p, n) / (p,) [rad/s in G's units]. Every QP algorithm keeps them at every level; the helpers
here put them into a level's QP in the level's own variables.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Lower bound standing in for "none" on one-sided rows (DAQP and PIQP read it as infinite).
NO_BOUND = -1e30
#: Tolerance on ``G x <= h`` when checking an unconstrained optimum.
FEASIBLE_TOL = 1e-10


@dataclass(slots=True)
class Inequalities:
    """Rows ``G qd <= h``: G (p, n), h (p,); p may be 0."""

    G: np.ndarray
    h: np.ndarray

    @property
    def rows(self) -> int:
        return self.h.shape[0]

    def satisfied(self, x: np.ndarray, tol: float = FEASIBLE_TOL) -> bool:
        """True when ``G x <= h + tol``."""
        return not self.rows or bool(np.all(self.G @ x <= self.h + tol))

    def violation(self, x: np.ndarray) -> float:
        """Largest ``G x - h`` above 0 (0 when satisfied or no rows)."""
        return float(max(np.max(self.G @ x - self.h), 0.0)) if self.rows else 0.0

    def reachable_within(self, lb: np.ndarray, ub: np.ndarray, slack: float = 1e-6) -> None:
        """Raise each ``h_i`` to at least the smallest ``G_i x`` the box ``[lb, ub]`` allows (in place).

        A row the box cannot meet (a pair closer than its damper allows, approaching faster than one
        step's acceleration can stop) asks for the most the box allows: brake that pair as hard as the
        joint limits permit. Each row is then feasible on its own; :meth:`relax_to` makes them jointly so.
        """
        if self.rows:
            least = np.minimum(self.G * lb, self.G * ub).sum(axis=1) + slack
            np.maximum(self.h, least, out=self.h)

    def binding(self, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
        """(p,) bool: the rows some velocity of the box ``[lb, ub]`` (n,) breaks; the others add nothing to the box."""
        most = np.maximum(self.G * lb, self.G * ub).sum(axis=1)
        return most > self.h

    def relax_to(self, x0: np.ndarray, slack: float = 1e-6) -> None:
        """Raise each ``h_i`` to at least ``G_i x0 + slack`` (in place), so that x0 (n,) meets every row.

        With x0 the braking velocity (the box's point nearest to rest), a row that even braking breaks (a
        pair already closer than the damper allows, moving too fast to stop within one step's
        acceleration) asks for no worse than braking: the rows stay jointly feasible with the box, and
        every other row keeps its damper.
        """
        if self.rows:
            np.maximum(self.h, self.G @ x0 + slack, out=self.h)


def level_rows(
    ineq: Inequalities | None, Z: np.ndarray | None, x: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The box and the rows of a null-space level ``x + Z z`` as one stack ``gl <= Gs z <= gu``.

    Args:
        ineq: the rows ``G qd <= h`` (None or empty: only the box).
        Z: (n, r) null-space basis of the levels above, or None for the first level (identity).
        x: (n,) solution of the levels above. lo, hi: (n,) the box shifted by x (``lb - x``, ``ub - x``).

    Returns:
        (Gs (n + p, r), gl, gu): ``[Z; G Z] z`` between ``[lo; -inf]`` and ``[hi; h - G x]``; or
        (None, None, None) when there are no rows (the level keeps its plain box).
    """
    if ineq is None or not ineq.rows:
        return None, None, None
    top = np.eye(x.shape[0]) if Z is None else Z
    Gs = np.vstack((top, ineq.G if Z is None else ineq.G @ Z))
    gl = np.concatenate((lo, np.full(ineq.rows, NO_BOUND)))
    gu = np.concatenate((hi, ineq.h - ineq.G @ x))
    return Gs, gl, gu
