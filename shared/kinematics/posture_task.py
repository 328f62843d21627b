"""Posture task: a small pull of every joint towards a reference posture."""

from __future__ import annotations

import numpy as np

from shared.kinematics.configuration import Configuration
from shared.kinematics.frame_task import _check
from shared.kinematics.task import Task


class PostureTask(Task):
    """Regularise joints towards ``q_target`` (n,) [rad].

    Error (n,): ``q_target - q`` [rad]. Jacobian: identity (n, n).

    Args:
        q_target: reference posture (n,) [rad], e.g. the rest pose.
        cost: weight of every joint row (scalar or (n,)).
        gain: proportional gain [1/s].
    """

    def __init__(self, q_target: np.ndarray, cost: float | np.ndarray = 1e-2, gain: float = 5.0):
        q_target = np.asarray(q_target, dtype=float)
        self.dim = q_target.shape[0]
        super().__init__("posture", np.broadcast_to(np.asarray(cost, dtype=float), (self.dim,)).copy(), gain)
        self.q_target = _check(q_target, (self.dim,), "posture target").copy()
        self._eye = np.eye(self.dim)
        self._err = np.zeros(self.dim)

    def set_target(self, q: np.ndarray) -> None:
        """New reference posture (n,) [rad]."""
        self.q_target[:] = _check(q, (self.dim,), "posture target")

    def compute_error(self, configuration: Configuration) -> np.ndarray:
        np.subtract(self.q_target, configuration.q, out=self._err)
        return self._err

    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        return self._eye

    def fill_qp_objective(self, configuration: Configuration, A: np.ndarray, b: np.ndarray) -> None:
        # A = diag(cost), without a dense product with the identity.
        A.fill(0.0)
        A.flat[:: self.dim + 1] = self.cost
        np.subtract(self.q_target, configuration.q, out=b)
        self._fill_b(b, b)
