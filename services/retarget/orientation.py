"""Orientation mapping, seed 000 eq. (4), and the rotation helpers it needs.

``W_R'_U = W_R'_H · H_R_U`` with the fixed offset ``H_R_U = (W_R_H)^-1 · W_R_U`` taken at
calibration: ``W_R_H`` is the operator bone's rest orientation and ``W_R_U`` the robot
frame's orientation at the profile rest pose. "W" is the pelvis frame on each side
(the HumanFrame is already expressed in the operator's pelvis frame, the targets in
the robot's). When the operator is at rest the robot target is exactly its rest
orientation, and every operator rotation is reproduced as the same rotation
expressed in the pelvis frame.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation from a unit quaternion (4,) w, x, y, z."""
    w, x, y, z = (float(v) for v in q)
    quat = pin.Quaternion(w, x, y, z)
    quat.normalize()
    return quat.toRotationMatrix()


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (4,) w, x, y, z with w >= 0 from a rotation (3, 3)."""
    quat = pin.Quaternion(np.asarray(R, dtype=float))
    quat.normalize()
    q = np.array([quat.w, quat.x, quat.y, quat.z])
    return -q if q[0] < 0 else q


def angular_velocity(R_prev: np.ndarray, R: np.ndarray, dt: float) -> np.ndarray:
    """Angular velocity (3,) [rad/s] in the base frame taking R_prev to R in dt [s]."""
    return pin.log3(R @ R_prev.T) / dt


class OrientationMap:
    """Eq. (4) for one target: fixed offset ``H_R_U`` from the two rest orientations.

    Args:
        R_H_rest: (3, 3) operator bone rest orientation ``W_R_H`` (operator pelvis frame).
        R_U_rest: (3, 3) robot frame rest orientation ``W_R_U`` (robot base frame).
    """

    def __init__(self, R_H_rest: np.ndarray, R_U_rest: np.ndarray):
        self.R_H_rest = np.asarray(R_H_rest, dtype=float)
        self.R_U_rest = np.asarray(R_U_rest, dtype=float)
        self.R_HU = self.R_H_rest.T @ self.R_U_rest  # (W_R_H)^-1 W_R_U; inverse of a rotation is its transpose

    def __call__(self, R_H: np.ndarray) -> np.ndarray:
        """Robot target orientation ``W_R'_U`` (3, 3) for operator orientation ``W_R'_H`` (3, 3)."""
        return np.asarray(R_H, dtype=float) @ self.R_HU
