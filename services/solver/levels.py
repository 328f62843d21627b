"""The task rows of each priority level, stacked into preallocated matrices once per tick."""

from __future__ import annotations

from collections.abc import Sequence
from itertools import chain

import numpy as np

from services.solver.frame_rows import FrameRows, batchable
from shared.kinematics import Configuration, Task


class LevelStack:
    """Preallocated stacked ``A_k`` (m_k, n) and ``b_k`` (m_k,) of each level, filled from its tasks.

    Args:
        levels: tasks by priority, highest first.
        n: number of joints.
        compiled: the position and pose tasks' arithmetic in the numba kernel (``FrameRows``).
    """

    def __init__(self, levels: Sequence[Sequence[Task]], n: int, compiled: bool = True):
        self.levels = [list(tasks) for tasks in levels]
        self.n = n
        self.key = _key(levels)
        sizes = [sum(t.dim for t in tasks) for tasks in self.levels]
        #: (L + 1,) row offsets of the levels in A_all / b_all.
        self.offsets = np.cumsum([0, *sizes]).astype(np.int64)
        #: Most rows on one level.
        self.max_rows = max(sizes, default=0)
        #: (sum m_k, n) and (sum m_k,): every level's rows in one buffer (the compiled HQP reads it whole);
        #: A and b are its per-level views.
        self.A_all = np.zeros((int(self.offsets[-1]), n))
        self.b_all = np.zeros(int(self.offsets[-1]))
        self.A: list[np.ndarray] = []
        self.b: list[np.ndarray] = []
        #: (task, its A rows, its b rows) of every task filled on its own (not by ``frame_rows``)
        self._rows: list[tuple[Task, np.ndarray, np.ndarray]] = []
        batched: list[tuple[Task, int]] = []
        for k, tasks in enumerate(self.levels):
            start = int(self.offsets[k])
            A = self.A_all[start : self.offsets[k + 1]]
            b = self.b_all[start : self.offsets[k + 1]]
            i = 0
            for t in tasks:
                if batchable(t):
                    batched.append((t, start + i))
                else:
                    self._rows.append((t, A[i : i + t.dim], b[i : i + t.dim]))
                i += t.dim
            self.A.append(A)
            self.b.append(b)
        #: the position and pose tasks' rows, filled together
        self.frame_rows = FrameRows(batched, n, compiled)

    def holds(self, levels: Sequence[Sequence[Task]], n: int) -> bool:
        """True when this stack was built for exactly these task objects and n joints."""
        return self.n == n and self.key == _key(levels)

    def fill(self, configuration: Configuration) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Evaluate every task at the configuration; returns the (A_k, b_k) lists (buffers reused)."""
        self.frame_rows.fill(configuration, self.A_all, self.b_all)
        for task, A, b in self._rows:
            task.fill_qp_objective(configuration, A, b)
        return self.A, self.b


def _key(levels: Sequence[Sequence[Task]]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The task objects' ids in order and the tasks per level (``map``: no Python-level loop, it runs every tick)."""
    return tuple(map(id, chain.from_iterable(levels))), tuple(map(len, levels))
