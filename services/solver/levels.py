"""The task rows of each priority level, stacked into preallocated matrices once per tick."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shared.kinematics import Configuration, Task


class LevelStack:
    """Preallocated stacked ``A_k`` (m_k, n) and ``b_k`` (m_k,) of each level, filled from its tasks.

    Args:
        levels: tasks by priority, highest first.
        n: number of joints.
    """

    def __init__(self, levels: Sequence[Sequence[Task]], n: int):
        self.levels = [list(tasks) for tasks in levels]
        self.n = n
        self.key = _key(levels)
        self.A: list[np.ndarray] = []
        self.b: list[np.ndarray] = []
        self._rows: list[tuple[Task, np.ndarray, np.ndarray]] = []
        for tasks in self.levels:
            m = sum(t.dim for t in tasks)
            A = np.zeros((m, n))
            b = np.zeros(m)
            i = 0
            for t in tasks:
                self._rows.append((t, A[i : i + t.dim], b[i : i + t.dim]))
                i += t.dim
            self.A.append(A)
            self.b.append(b)

    def holds(self, levels: Sequence[Sequence[Task]], n: int) -> bool:
        """True when this stack was built for exactly these task objects and n joints."""
        return self.n == n and self.key == _key(levels)

    def fill(self, configuration: Configuration) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Evaluate every task at the configuration; returns the (A_k, b_k) lists (buffers reused)."""
        for task, A, b in self._rows:
            task.fill_qp_objective(configuration, A, b)
        return self.A, self.b


def _key(levels: Sequence[Sequence[Task]]) -> tuple[tuple[int, ...], ...]:
    return tuple(tuple(id(t) for t in tasks) for tasks in levels)
