"""What every solver algorithm shares: prioritised levels in, joint velocities out.

An algorithm takes ``levels: Sequence[Sequence[Task]]`` (level 0 first = highest
priority) plus joint limits and returns a :class:`Solution`. Algorithms whose
math only needs the stacked matrices implement :meth:`Algorithm.solve_matrices`,
which the random-problem tests drive directly with random Jacobians.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from shared.kinematics import Configuration, Limit, Task, velocity_bounds

#: Box violation [rad/s] tolerated from a QP solver's own tolerance before clipping silently.
QP_BOUND_TOL = 1e-7
#: Tolerance [rad/s] on bounds when checking an unconstrained optimum.
FEASIBLE_TOL = 1e-10


@dataclass(slots=True)
class Solution:
    """Result of one solve.

    Attributes:
        qd: (n,) joint velocities [rad/s].
        residuals: per level, ``||A_k qd - b_k||`` (weighted task-velocity residual).
        ok: False when the solve failed and qd must not be used.
        iters: QP iterations summed over levels (0 for closed-form steps).
        qp_calls: how many QPs were solved (levels whose unconstrained optimum broke a bound).
        active: number of joints at one of their velocity bounds.
        reason: why, when not ok or when a lower level was dropped.
    """

    qd: np.ndarray
    residuals: list[float] = field(default_factory=list)
    ok: bool = True
    iters: int = 0
    qp_calls: int = 0
    active: int = 0
    reason: str = ""


class LevelStack:
    """Preallocated stacked ``A_k`` (m_k, n) and ``b_k`` (m_k,) of each level, filled from its tasks."""

    def __init__(self, levels: Sequence[Sequence[Task]], n: int):
        self.levels = [list(tasks) for tasks in levels]
        self.key = tuple(id(t) for tasks in self.levels for t in tasks)
        self.A: list[np.ndarray] = []
        self.b: list[np.ndarray] = []
        self._rows: list[list[tuple[Task, np.ndarray, np.ndarray]]] = []
        for tasks in self.levels:
            m = sum(t.dim for t in tasks)
            A = np.zeros((m, n))
            b = np.zeros(m)
            rows, i = [], 0
            for t in tasks:
                rows.append((t, A[i : i + t.dim], b[i : i + t.dim]))
                i += t.dim
            self.A.append(A)
            self.b.append(b)
            self._rows.append(rows)

    def fill(self, configuration: Configuration) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Evaluate every task at the configuration; returns the (A_k, b_k) lists (buffers reused)."""
        for rows in self._rows:
            for task, A, b in rows:
                task.fill_qp_objective(configuration, A, b)
        return self.A, self.b


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


def clip(x: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """x clipped into [lb, ub] in place (np.clip costs several times more on small vectors)."""
    return np.minimum(np.maximum(x, lb, out=x), ub, out=x)


class Algorithm(ABC):
    """A velocity-level solver over prioritised levels of tasks with hard joint limits."""

    name: str = ""

    def __init__(self) -> None:
        self._stack: LevelStack | None = None
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None

    def stack(self, levels: Sequence[Sequence[Task]], n: int) -> LevelStack:
        """The cached LevelStack for these levels (rebuilt when the tasks change)."""
        key = tuple(id(t) for tasks in levels for t in tasks)
        if self._stack is None or self._stack.key != key or self._stack.A[0].shape[1] != n:
            self._stack = LevelStack(levels, n)
        return self._stack

    def bounds(self, limits: Sequence[Limit], configuration: Configuration, dt: float):
        """Velocity bounds (lb, ub) (n,) [rad/s] of all limits, in reused buffers (also kept as ``last_bounds``)."""
        n = configuration.nv
        if self._bounds is None or self._bounds[0].shape[0] != n:
            self._bounds = (np.empty(n), np.empty(n))
        return velocity_bounds(limits, configuration, dt, out=self._bounds)

    @property
    def last_bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The bounds used by the last :meth:`solve` (None before the first)."""
        return self._bounds

    def solve(
        self,
        configuration: Configuration,
        levels: Sequence[Sequence[Task]],
        limits: Sequence[Limit],
        dt: float,
    ) -> Solution:
        """Joint velocities for one step dt [s] from the configuration.

        Args:
            configuration: current robot configuration (kinematics up to date).
            levels: tasks by priority, highest first.
            limits: joint limits, hard at every level.
            dt: step [s].
        """
        if not levels or not levels[0]:
            raise ValueError("at least one level with one task is needed")
        As, bs = self.stack(levels, configuration.nv).fill(configuration)
        lb, ub = self.bounds(limits, configuration, dt)
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


def polish(
    M: np.ndarray,
    c: np.ndarray,
    z: np.ndarray,
    G: np.ndarray | None,
    lo: np.ndarray,
    hi: np.ndarray,
    E: np.ndarray | None = None,
    e: np.ndarray | None = None,
    eps: float = 0.0,
    act_tol: float = 1e-5,
) -> np.ndarray:
    """Refine a QP solution of ``min ||M z - c||^2 + eps ||z||^2`` s.t. ``lo <= G z <= hi``, ``E z = e``.

    Interior-point solvers stop at a tolerance, and a least-squares objective
    accurate to 1e-10 only pins the task value to about 1e-5. With the active
    set read off the QP solution, the exact optimum is an equality-constrained
    least squares: solved here by a null-space step and accepted only when it
    stays in the box and does not raise the objective.

    Args:
        M: (m, r), c: (m,), z: (r,) QP solution. G: (p, r) rows bounded by lo, hi (p,); None = identity.
        E, e: optional equality rows (q, r) and values (q,).
        eps: the QP's Tikhonov weight (kept in the refined problem).
        act_tol: distance to a bound under which a row counts as active.
    """
    from services.solver.linalg import split_row_space  # local: linalg imports nothing from here

    def objective(x: np.ndarray) -> float:
        r = M @ x - c
        return float(r @ r + eps * (x @ x))

    g = z if G is None else G @ z
    at_lo = g <= lo + act_tol
    at_hi = g >= hi - act_tol
    act = at_lo | at_hi
    rows = [] if E is None else [E]
    vals = [] if E is None else [e]
    if act.any():
        Ga = np.eye(z.shape[0])[act] if G is None else G[act]
        rows.append(Ga)
        vals.append(np.where(at_lo, lo, hi)[act])
    if rows:
        C = np.vstack(rows)
        d = np.concatenate(vals)
        split = split_row_space(C)
        z0 = split.lstsq(d)
        if np.linalg.norm(C @ z0 - d) > 1e-9 * (1.0 + np.linalg.norm(d)):
            return z
        N = split.null_basis
    else:
        z0 = np.zeros_like(z)
        N = np.eye(z.shape[0])
    if N.shape[1]:
        MN = M @ N
        rhs = c - M @ z0
        if eps:
            # Damped: min ||MN w - rhs||^2 + eps ||z0 + N w||^2, with N orthonormal.
            H = MN.T @ MN
            H.flat[:: H.shape[0] + 1] += eps
            w = np.linalg.solve(H, MN.T @ rhs - eps * (N.T @ z0))
        else:
            w = split_row_space(MN).lstsq(rhs)
        zp = z0 + N @ w
    else:
        zp = z0
    gp = zp if G is None else G @ zp
    if ((gp < lo - FEASIBLE_TOL) | (gp > hi + FEASIBLE_TOL)).any():
        return z
    if E is not None and np.linalg.norm(E @ zp - e) > 1e-9 * (1.0 + np.linalg.norm(e)):
        return z
    if objective(zp) > objective(z) + 1e-12:
        return z
    return zp
