"""Pose task on a frame (the wrists): position and orientation in the base frame."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from shared.kinematics.configuration import Configuration
from shared.kinematics.exceptions import InvalidTargetError
from shared.kinematics.task import Task


def _check(x: np.ndarray, shape: tuple[int, ...], what: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.shape != shape or not np.all(np.isfinite(x)):
        raise InvalidTargetError(f"{what}: expected finite array of shape {shape}, got {x.shape}")
    return x


class FrameTask(Task):
    """Drive a frame to a target pose (both expressed in the base frame).

    Error (6,): ``[p_target - p (3,) [m]; log3(R_target R^T) (3,) [rad]]``, the
    rotation vector in the base frame that turns the current orientation into
    the target one. Jacobian: the frame's LOCAL_WORLD_ALIGNED Jacobian.

    Args:
        frame: target name (``left_wrist``) or frame name.
        position_cost: weight of the 3 position rows [1/m].
        orientation_cost: weight of the 3 orientation rows [1/rad]; 0 tracks position only.
        gain: proportional gain [1/s].
    """

    dim = 6

    def __init__(self, frame: str, position_cost: float = 1.0, orientation_cost: float = 1.0, gain: float = 50.0):
        super().__init__(f"frame:{frame}", np.r_[np.full(3, position_cost), np.full(3, orientation_cost)], gain)
        self.frame = frame
        self.p_target = np.zeros(3)
        self.R_target = np.eye(3)
        self._err = np.zeros(6)

    def set_orientation_cost(self, cost: float) -> None:
        """Change the orientation rows' weight (0 disables orientation tracking)."""
        self.cost[3:] = cost

    def set_target(
        self,
        p: np.ndarray,
        R: np.ndarray,
        v: np.ndarray | None = None,
        w: np.ndarray | None = None,
        check: bool = True,
    ) -> None:
        """Target pose p (3,) [m], R (3, 3) and its velocity v (3,) [m/s], w (3,) [rad/s] (base frame).

        ``check=False`` skips validation, for callers whose inputs were validated upstream.
        """
        if check:
            p = _check(p, (3,), f"{self.name} position")
            R = _check(R, (3, 3), f"{self.name} rotation")
            v = None if v is None else _check(v, (3,), f"{self.name} velocity")
            w = None if w is None else _check(w, (3,), f"{self.name} angular velocity")
        self.p_target[:] = p
        self.R_target[:] = R
        self._ff[:3] = 0.0 if v is None else v
        self._ff[3:] = 0.0 if w is None else w

    def set_target_from_configuration(self, configuration: Configuration) -> None:
        """Hold the frame where it is now, at rest."""
        p, R = configuration.get_frame_pose(self.frame)
        self.set_target(p, R, check=False)

    def compute_error(self, configuration: Configuration) -> np.ndarray:
        p, R = configuration.get_frame_pose(self.frame)
        np.subtract(self.p_target, p, out=self._err[:3])
        self._err[3:] = pin.log3(self.R_target @ R.T)
        return self._err

    def compute_jacobian(self, configuration: Configuration) -> np.ndarray:
        return configuration.get_frame_jacobian(self.frame)

    def fill_qp_objective(self, configuration: Configuration, A: np.ndarray, b: np.ndarray) -> None:
        # The error straight into b (the base class's steps, fewer calls: this runs several times a tick).
        np.multiply(self._cost_col, configuration.get_frame_jacobian(self.frame), out=A)
        p, R = configuration.get_frame_pose(self.frame)
        np.subtract(self.p_target, p, out=b[:3])
        b[3:] = pin.log3(self.R_target @ R.T)
        self._fill_b(b, b)
