"""The contract every solver algorithm honours: prioritised levels and joint bounds in, a Solution out.

An algorithm is given the stacked task rows of each level, ``A_k`` (m_k, n) and
``b_k`` (m_k,), level 0 first (highest priority), and the joint-velocity box
``lb <= qd <= ub`` (n,) [rad/s] that the caller built from every joint limit
(``bounds.JointBounds``), held together as one :class:`LevelProblem`. It implements one
method, :meth:`Algorithm.solve_problem`; :meth:`Algorithm.solve` (tasks at a configuration)
and :meth:`Algorithm.solve_matrices` (stacked rows) only build the problem. The residuals it
reports are always ``||A_k qd - b_k||`` of the qd it returns (:meth:`LevelProblem.solution`),
so the status the service derives from them means the same for every algorithm.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from services.solver.inequalities import Inequalities
from services.solver.levels import LevelStack
from shared.kinematics import Configuration, Task

#: Box violation [rad/s] tolerated from a QP solver's own tolerance before clipping silently.
QP_BOUND_TOL = 1e-7
#: Tolerance [rad/s] on bounds when checking an unconstrained optimum.
FEASIBLE_TOL = 1e-10


@dataclass(slots=True)
class Solution:
    """Result of one solve.

    Attributes:
        qd: (n,) joint velocities [rad/s], inside the bounds when ok.
        residuals: per level, ``||A_k qd - b_k||`` (weighted task-velocity residual of this qd).
        ok: False when the solve failed and qd must not be used.
        iters: QP iterations summed over levels (0 for closed-form steps).
        qp_calls: how many QPs were solved (levels whose unconstrained optimum broke a bound).
        active: number of joints at one of their velocity bounds.
        reason: why, when not ok or when a lower level was dropped or the result clamped.
    """

    qd: np.ndarray
    residuals: list[float] = field(default_factory=list)
    ok: bool = True
    iters: int = 0
    qp_calls: int = 0
    active: int = 0
    reason: str = ""


def level_residuals(As: Sequence[np.ndarray], bs: Sequence[np.ndarray], x: np.ndarray) -> list[float]:
    """``||A_k x - b_k||`` for each level."""
    out = []
    for A, b in zip(As, bs):
        r = A @ x
        r -= b
        out.append(math.sqrt(r @ r))
    return out


def level_value(values: float | Sequence[float], k: int) -> float:
    """Per-level setting: a scalar for every level, or one value per level with the last repeated."""
    if isinstance(values, (int, float)):
        return float(values)
    return float(values[min(k, len(values) - 1)])


def count_active(x: np.ndarray, lb: np.ndarray, ub: np.ndarray, tol: float = 1e-9) -> int:
    """Number of entries of x within tol of a bound."""
    return int(np.count_nonzero((x <= lb + tol) | (x >= ub - tol)))


def within(x: np.ndarray, lb: np.ndarray, ub: np.ndarray, tol: float = FEASIBLE_TOL) -> bool:
    """True when lb - tol <= x <= ub + tol everywhere."""
    return not ((x < lb - tol) | (x > ub + tol)).any()


def violation(x: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> float:
    """Largest distance of x outside [lb, ub] (0 inside)."""
    return float(max(np.max(lb - x), np.max(x - ub), 0.0))


def clip(x: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """x clipped into [lb, ub] in place (np.clip costs several times more on small vectors)."""
    return np.minimum(np.maximum(x, lb, out=x), ub, out=x)


@dataclass(slots=True)
class LevelProblem:
    """One solve: levels ``min ||A_k x - b_k||`` in priority order, with ``lb <= x <= ub`` and ``G x <= h``.

    Attributes:
        As: per level (m_k, n) task matrices, level 0 (highest priority) first. bs: per level (m_k,) targets.
        lb, ub: (n,) joint-velocity bounds [rad/s] with lb <= ub.
        ineq: optional inequality rows; an empty set is dropped (None), so algorithms test for None only.
        configuration, levels: the configuration and the tasks the rows were evaluated from, when solved
            through :meth:`Algorithm.solve` (None from :meth:`Algorithm.solve_matrices`), for algorithms
            that use more of a task than its rows (clik-mimicry's alignment gradient).
    """

    As: Sequence[np.ndarray]
    bs: Sequence[np.ndarray]
    lb: np.ndarray
    ub: np.ndarray
    ineq: Inequalities | None = None
    configuration: Configuration | None = None
    levels: Sequence[Sequence[Task]] | None = None

    def __post_init__(self) -> None:
        if self.ineq is not None and not self.ineq.rows:
            self.ineq = None

    @property
    def n(self) -> int:
        """Number of variables (joints)."""
        return self.lb.shape[0]

    @property
    def mid(self) -> np.ndarray:
        """(n,) centre of the box [rad/s] (the cascades damp towards it, not towards zero)."""
        return 0.5 * (self.lb + self.ub)

    def solution(self, x: np.ndarray, ok: bool = True, iters: int = 0, qp_calls: int = 0, reason: str = "") -> Solution:
        """The Solution for x (n,): its residuals on every level, and its active bounds when ok (0 when not)."""
        active = count_active(x, self.lb, self.ub) if ok else 0
        return Solution(x, level_residuals(self.As, self.bs, x), ok, iters, qp_calls, active, reason)

    def clamped(self, qd: np.ndarray) -> Solution:
        """The clamping baselines' answer: qd (n,) clamped into the box, the reason saying how many joints moved."""
        x = np.minimum(np.maximum(qd, self.lb), self.ub)
        moved = int(np.count_nonzero(x != qd))
        return self.solution(x, reason=f"clamped {moved} joints" if moved else "")


class Algorithm(ABC):
    """A velocity-level solver over prioritised levels of tasks with hard joint bounds."""

    name: str = ""

    def __init__(self) -> None:
        self._stack: LevelStack | None = None

    def stack(self, levels: Sequence[Sequence[Task]], n: int) -> LevelStack:
        """The cached LevelStack for these levels (rebuilt when the tasks change)."""
        if self._stack is None or not self._stack.holds(levels, n):
            self._stack = LevelStack(levels, n)
        return self._stack

    def solve(
        self,
        configuration: Configuration,
        levels: Sequence[Sequence[Task]],
        lb: np.ndarray,
        ub: np.ndarray,
        ineq: Inequalities | None = None,
    ) -> Solution:
        """Joint velocities (n,) [rad/s] from the tasks evaluated at the configuration.

        Args:
            configuration: current robot configuration (kinematics up to date).
            levels: tasks by priority, highest first (at least one task on the first level).
            lb, ub: (n,) joint-velocity bounds [rad/s] with lb <= ub, hard at every level.
            ineq: optional rows ``G qd <= h`` (self-collision dampers), hard at every level of the QP
                algorithms; the clamping baselines (clik-nullspace, clik-mimicry, dls) cannot honour them.
        """
        if not levels or not levels[0]:
            raise ValueError("at least one level with one task is needed")
        As, bs = self.stack(levels, configuration.nv).fill(configuration)
        return self.solve_problem(LevelProblem(As, bs, lb, ub, ineq, configuration, levels))

    def solve_matrices(
        self,
        As: Sequence[np.ndarray],
        bs: Sequence[np.ndarray],
        lb: np.ndarray,
        ub: np.ndarray,
        ineq: Inequalities | None = None,
    ) -> Solution:
        """Solve stacked rows directly (see :class:`LevelProblem` for the arguments)."""
        return self.solve_problem(LevelProblem(As, bs, lb, ub, ineq))

    @abstractmethod
    def solve_problem(self, p: LevelProblem) -> Solution:
        """Solve the levels of p in priority order within its bounds (and its inequality rows, if it can)."""
