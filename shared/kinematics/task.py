"""Task base: an error to drive to zero and its Jacobian.

A velocity-level task asks for joint velocities qd (n,) [rad/s] with
``J qd = v_ff + gain * e``: the target's own velocity fed forward plus a
proportional correction of the error ``e = target ⊖ current``. The solver
gets it as the weighted least-squares row block ``A = W J``, ``b = W (v_ff +
gain e)``, ``W = diag(cost)``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from shared.kinematics.configuration import Configuration


class Task(ABC):
    """A task of dimension ``dim`` with per-row costs and a proportional gain.

    Attributes:
        name: label used in reports.
        dim: number of rows m.
        cost: (m,) row weights (dimensionless scaling of each error row).
        gain: proportional gain [1/s] on the error.
    """

    dim: int

    def __init__(self, name: str, cost: np.ndarray, gain: float):
        if gain < 0 or not np.isfinite(gain):
            raise ValueError(f"{name}: gain must be finite and >= 0, got {gain}")
        cost = np.asarray(cost, dtype=float)
        if cost.shape != (self.dim,) or np.any(cost < 0) or not np.all(np.isfinite(cost)):
            raise ValueError(f"{name}: cost must be {self.dim} finite values >= 0, got {cost}")
        self.name = name
        self.cost = cost
        #: (m, 1) view of cost for the row scaling of A (cost is only ever changed in place)
        self._cost_col = cost[:, None]
        self.gain = float(gain)
        self._ff = np.zeros(self.dim)

    @abstractmethod
    def compute_error(self, configuration: Configuration) -> np.ndarray:
        """(m,) error ``target ⊖ current`` in task units ([m], [rad])."""

    @abstractmethod
    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        """(m, n) Jacobian of the task quantity: task velocity = J qd."""

    def feedforward(self) -> np.ndarray:
        """(m,) target velocity fed forward [task units / s]."""
        return self._ff

    def fill_qp_objective(self, configuration: Configuration, A: np.ndarray, b: np.ndarray) -> None:
        """Write ``A = W J`` (m, n) and ``b = W (v_ff + gain e)`` (m,) into the given buffers."""
        np.multiply(self._cost_col, self.compute_jacobian(configuration), out=A)
        self._fill_b(self.compute_error(configuration), b)

    def _fill_b(self, e: np.ndarray, b: np.ndarray) -> None:
        """``b = W (v_ff + gain e)`` in place (b may already hold e): no temporaries, the same bits."""
        np.multiply(e, self.gain, out=b)
        b += self.feedforward()
        b *= self.cost

    def compute_qp_objective(self, configuration: Configuration) -> tuple[np.ndarray, np.ndarray]:
        """(A (m, n), b (m,)) of the least-squares objective ``||A qd - b||^2``."""
        A = np.empty((self.dim, configuration.nv))
        b = np.empty(self.dim)
        self.fill_qp_objective(configuration, A, b)
        return A, b
