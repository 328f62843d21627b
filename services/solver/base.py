"""The contract every solver algorithm honours: prioritised levels and joint bounds in, a Solution out.

An algorithm is given the stacked task rows of each level, ``A_k`` (m_k, n) and
``b_k`` (m_k,), level 0 first (highest priority), and the joint-velocity box
``lb <= qd <= ub`` (n,) [rad/s] that the caller built from every joint limit
(``bounds.JointBounds``). It implements one method, :meth:`Algorithm.solve_matrices`;
:meth:`Algorithm.solve` only evaluates the tasks at a configuration first. The
residuals it reports are always ``||A_k qd - b_k||`` of the qd it returns, so the
status the service derives from them means the same for every algorithm.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

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
        self, configuration: Configuration, levels: Sequence[Sequence[Task]], lb: np.ndarray, ub: np.ndarray
    ) -> Solution:
        """Joint velocities (n,) [rad/s] from the tasks evaluated at the configuration.

        Args:
            configuration: current robot configuration (kinematics up to date).
            levels: tasks by priority, highest first (at least one task on the first level).
            lb, ub: (n,) joint-velocity bounds [rad/s] with lb <= ub, hard at every level.
        """
        if not levels or not levels[0]:
            raise ValueError("at least one level with one task is needed")
        As, bs = self.stack(levels, configuration.nv).fill(configuration)
        return self.solve_matrices(As, bs, lb, ub)

    @abstractmethod
    def solve_matrices(
        self,
        As: Sequence[np.ndarray],
        bs: Sequence[np.ndarray],
        lb: np.ndarray,
        ub: np.ndarray,
    ) -> Solution:
        """Solve levels ``min ||A_k x - b_k||`` (priority order) with ``lb <= x <= ub``.

        Args:
            As: per level (m_k, n) task matrices. bs: per level (m_k,) targets.
            lb, ub: (n,) bounds with lb <= ub.
        """
