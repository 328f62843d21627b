"""The rows of every frame task (``PositionTask``, ``FrameTask``) of a level stack, filled together.

Per task, ``fill_qp_objective`` costs about ten Python-level calls (the frame's pose and Jacobian, the
error, ``b = W (v_ff + gain e)``); a stack holds eight such tasks (wrist and elbow positions, wrist and
elbow orientations), most of a tick's task construction. Here each frame's pose and Jacobian is read
once, the targets, feed-forwards, costs and gains of all tasks are gathered with one concatenation
each, and ``A = W J``, ``b`` are computed for every row at once and scattered into the stack. Only the
orientation errors (``log3``) stay per task. The arithmetic per element is the tasks' own (same
operations, same order), so the rows are bit for bit those of ``fill_qp_objective``, which stays the
reference (``tests/solver/test_frame_rows.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from shared.kinematics import Configuration, FrameTask, PositionTask, Task


def batchable(task: Task) -> bool:
    """True for the task types whose rows :class:`FrameRows` fills (exactly these classes: a subclass may
    change the rows)."""
    return type(task) in (PositionTask, FrameTask)


class FrameRows:
    """Fills the rows of position and pose tasks into a stack's ``A_all`` (R, n) and ``b_all`` (R,).

    Args:
        tasks: the batchable tasks (``batchable``), each with the first row it owns in the stack.
        n: number of joints.
        compiled: the arithmetic in the numba kernel (``tick_kernel.frame_rows``, compiled when built); False
            runs the numpy steps, the readable reference the kernel is tested against. Both give the same bits.
    """

    def __init__(self, tasks: Sequence[tuple[Task, int]], n: int, compiled: bool = True):
        self.tasks = [t for t, _ in tasks]
        self.frames = list(dict.fromkeys(t.frame for t in self.tasks))
        slot = {f: i for i, f in enumerate(self.frames)}
        dst, src, pos_rows, pos_src, row_task = [], [], [], [], []
        #: (task, first row of its orientation error in the batch) of each pose task
        self._poses: list[tuple[FrameTask, int, int]] = []
        r = 0
        for i, (t, start) in enumerate(tasks):
            f = slot[t.frame]
            dst.extend(range(start, start + t.dim))
            src.extend(range(6 * f, 6 * f + t.dim))  # Jacobian rows: linear (3), then angular (3)
            pos_rows.extend(range(r, r + 3))
            pos_src.extend(range(3 * f, 3 * f + 3))
            row_task.extend([i] * t.dim)
            if t.dim == 6:
                self._poses.append((t, r + 3, f))
            r += t.dim
        #: rows of the stack each batch row goes to, and the stacked-Jacobian row it scales
        self.dst = np.array(dst, dtype=np.intp)
        self._src = np.array(src, dtype=np.intp)
        self._pos_rows = np.array(pos_rows, dtype=np.intp)
        self._pos_src = np.array(pos_src, dtype=np.intp)
        self._row_task = np.array(row_task, dtype=np.intp)
        F = len(self.frames)
        self._J = np.empty((6 * F, n))  # every frame's (6, n) Jacobian, stacked
        self._p = np.empty(3 * F)  # every frame's position [m], stacked
        self._e = np.empty(r)  # the error rows
        # The arrays the tasks write their targets, costs and feed-forwards into (in place: the tasks never rebind
        # them), listed once for the per-tick gathers, into kept buffers.
        self._p_targets = [t.p_target for t in self.tasks]
        self._costs = [t.cost for t in self.tasks]
        self._ffs = [t.feedforward() for t in self.tasks]
        self._p_target = np.empty(sum(a.shape[0] for a in self._p_targets))
        self._cost = np.empty(r)
        self._ff = np.empty(r)
        self._kernel = None
        if compiled and self.tasks:
            from services.solver import tick_kernel

            tick_kernel.warm_up()
            self._kernel = tick_kernel

    def fill(self, configuration: Configuration, A_all: np.ndarray, b_all: np.ndarray) -> None:
        """Write every task's ``A = W J`` and ``b = W (v_ff + gain e)`` into its rows of A_all and b_all."""
        if not self.tasks:
            return
        poses = [configuration.get_frame_pose(f) for f in self.frames]
        np.concatenate([configuration.get_frame_jacobian(f) for f in self.frames], out=self._J)
        np.concatenate([p for p, _ in poses], out=self._p)
        tasks = self.tasks
        e = self._e
        for t, r, f in self._poses:
            e[r : r + 3] = pin.log3(t.R_target @ poses[f][1].T)
        p_target = np.concatenate(self._p_targets, out=self._p_target)
        cost = np.concatenate(self._costs, out=self._cost)
        ff = np.concatenate(self._ffs, out=self._ff)
        if self._kernel is not None:
            self._kernel.frame_rows(
                e, p_target, self._p, self._pos_rows, self._pos_src, np.array([t.gain for t in tasks]),
                self._row_task, ff, cost, self._J, self._src, self.dst, A_all, b_all,
            )  # fmt: skip
            return
        e[self._pos_rows] = p_target - self._p[self._pos_src]
        # The tasks' own steps (``Task._fill_b``): the same operations in the same order, the same bits.
        b = e * np.array([t.gain for t in tasks])[self._row_task]
        b += ff
        b *= cost
        b_all[self.dst] = b
        A_all[self.dst] = cost[:, None] * self._J[self._src]
