"""Every solver algorithm by name: ``make_algorithm("hqp-nullspace", "daqp", damping)``."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from services.solver.base import Algorithm
from services.solver.clik_mimicry import ClikMimicry
from services.solver.clik_nullspace import ClikNullspace
from services.solver.dls import DampedLeastSquares
from services.solver.hqp_nullspace import HqpNullspace
from services.solver.hqp_original import HqpOriginal
from services.solver.qp import make_backend
from services.solver.wqp import WeightedQp

ALGORITHMS: dict[str, Callable[[str, tuple[float, ...]], Algorithm]] = {
    "hqp-nullspace": lambda qp, damping: HqpNullspace(make_backend(qp), eps=damping),
    "hqp-original": lambda qp, damping: HqpOriginal(make_backend(qp), eps=damping),
    "wqp": lambda qp, damping: WeightedQp(make_backend(qp), eps=damping),
    "clik-nullspace": lambda qp, damping: ClikNullspace(damping=damping[0]),
    "clik-mimicry": lambda qp, damping: ClikMimicry(damping=damping[0]),
    "dls": lambda qp, damping: DampedLeastSquares(damping=max(damping[0], 1e-6)),
}
#: Algorithms that call a QP backend (the others ignore ``--qp``).
USES_QP = ("hqp-nullspace", "hqp-original", "wqp")


def make_algorithm(name: str, qp: str = "piqp", damping: float | Sequence[float] = 1e-9) -> Algorithm:
    """Algorithm by name with the given QP backend and per-level damping; errors list the valid names."""
    damping = (float(damping),) if isinstance(damping, (int, float)) else tuple(float(d) for d in damping)
    if not damping or not all(0.0 <= d < 1.0 for d in damping):
        raise ValueError(f"damping must be values in [0, 1), got {damping}")
    make_backend(qp)  # validate the backend name for every algorithm
    try:
        factory = ALGORITHMS[name]
    except KeyError:
        raise ValueError(f"unknown algorithm {name!r}; choose one of {sorted(ALGORITHMS)}") from None
    return factory(qp, damping)
