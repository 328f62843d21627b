"""Position task on a frame's origin (the elbows)."""

from __future__ import annotations

import numpy as np

from shared.kinematics.configuration import Configuration
from shared.kinematics.frame_task import _check
from shared.kinematics.task import Task


class PositionTask(Task):
    """Drive a frame origin to a target point in the base frame.

    Error (3,): ``p_target - p`` [m]. Jacobian: the linear rows of the frame's
    LOCAL_WORLD_ALIGNED Jacobian (3, n).

    Args:
        frame: target name (``left_elbow``) or frame name.
        cost: weight of the rows [1/m].
        gain: proportional gain [1/s].
    """

    dim = 3

    def __init__(self, frame: str, cost: float = 1.0, gain: float = 50.0):
        super().__init__(f"position:{frame}", np.full(3, cost), gain)
        self.frame = frame
        self.p_target = np.zeros(3)
        self._err = np.zeros(3)

    def set_target(self, p: np.ndarray, v: np.ndarray | None = None, check: bool = True) -> None:
        """Target point p (3,) [m] moving at v (3,) [m/s] (base frame); ``check=False`` skips validation."""
        if check:
            p = _check(p, (3,), f"{self.name} position")
            v = None if v is None else _check(v, (3,), f"{self.name} velocity")
        self.p_target[:] = p
        self._ff[:] = 0.0 if v is None else v

    def set_target_from_configuration(self, configuration: Configuration) -> None:
        """Hold the point where it is now, at rest."""
        self.set_target(configuration.get_frame_pose(self.frame)[0], check=False)

    def compute_error(self, configuration: Configuration) -> np.ndarray:
        np.subtract(self.p_target, configuration.get_frame_pose(self.frame)[0], out=self._err)
        return self._err

    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        return configuration.get_frame_jacobian(self.frame)[:3]

    def fill_qp_objective(self, configuration: Configuration, A: np.ndarray, b: np.ndarray) -> None:
        # The error straight into b (the base class's steps, fewer calls: this runs several times a tick).
        np.multiply(self._cost_col, configuration.get_frame_jacobian(self.frame)[:3], out=A)
        np.subtract(self.p_target, configuration.get_frame_pose(self.frame)[0], out=b)
        self._fill_b(b, b)
