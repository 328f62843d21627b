"""What the three QP algorithms share (hqp-nullspace, hqp-original, wqp): a QP backend and per-level damping."""

from __future__ import annotations

from collections.abc import Sequence

from services.solver.base import Algorithm, level_value
from services.solver.qp import QpBackend

#: Regularisation of the one retry of a level whose QP failed.
RETRY_EPS = 1e-6
#: Widening [rad/s] of a level QP's box, rows and equalities for the last retry of a level whose QP failed with
#: and without ``RETRY_EPS``. When the levels above left qd exactly on joint bounds, the level's feasible set is
#: a face of zero width (the largest margin inside it measured 1e-13 to 1e-11 rad/s on real clips), and
#: round-off decides whether DAQP and PIQP find it empty; the level was then dropped and qd jumped by 0.5-1
#: rad/s (s6/h13n, h12b). Dropped levels in the eval of five real clips: 9 without this retry, 6 at 1e-9
#: (DAQP's primal_tol), 2 at 1e-8, 1 at 3e-8 (a face that needs 1e-5); 1e-7 is the caller's ``QP_BOUND_TOL``,
#: so answers on that box fail its check. The caller clips the answer back onto the box; it is the optimum
#: over the slightly larger face, within ~1e-3 rad/s of the other path's on the same problems.
RETRY_WIDEN = 3e-8
#: Widening [rad/s] of the very last retry (hqp-nullspace), for the faces ``RETRY_WIDEN`` does not open: with the
#: targets extrapolated along a parabola (``SolverConfig.target_acceleration``, the default since session 11)
#: dash_active and kick_normal lost level 2 once at 3e-8 (``tests/solver/test_degenerate_levels.py``). Its answer
#: is accepted within this much of the box and clipped onto it, which moves qd by at most this (1e-5 rad/s for one
#: tick: 2e-8 rad), against the 0.5-1 rad/s jump of a dropped level.
LAST_RETRY_WIDEN = 1e-5


class CascadeQp(Algorithm):
    """Base of the algorithms that solve QPs over the levels.

    Args:
        backend: QP backend for the levels that need one.
        eps: damping ``eps ||x||^2`` of each level's objective: one value, or one per level with the last
            repeated. Tiny (1e-9) gives the exact lexicographic optimum; the service uses
            ``SolverConfig.damping``.
        refine: refine each QP solution on its active set (``active_set.refine_on_active_set``); None =
            only for PIQP, whose interior-point answer is tolerance-limited (DAQP's active set is exact).
    """

    def __init__(self, backend: QpBackend, eps: float | Sequence[float] = 1e-9, refine: bool | None = None):
        super().__init__()
        self.backend = backend
        self.eps = eps
        self.refine = backend.name == "piqp" if refine is None else refine

    def level_eps(self, k: int) -> float:
        """Damping of level k (0-based)."""
        return level_value(self.eps, k)
