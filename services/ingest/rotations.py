"""Rotation helpers on stacked arrays (wxyz quaternions, 3x3 matrices).

Thin wrappers over :class:`scipy.spatial.transform.Rotation` so the rest of
the package speaks the bus convention (scalar-first ``w, x, y, z``).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

#: Axis change from a Y-up capture world (forward +Z, left +X, the usual BVH
#: convention) to our Z-up world (x forward, y left, z up): ``p_zup = A @ p_yup``.
#: It is a cyclic axis permutation, hence a proper rotation (det = +1).
Y_UP_TO_Z_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def euler_to_matrix(order: str, angles_deg: np.ndarray) -> np.ndarray:
    """Rotation matrices from BVH rotation channels.

    Args:
        order: axes in channel order, e.g. ``"ZXY"``; BVH applies them as
            intrinsic rotations, ``R = R_Z(a0) @ R_X(a1) @ R_Y(a2)``.
        angles_deg: (T, len(order)) angles [deg].

    Returns:
        (T, 3, 3) rotation matrices.
    """
    return Rotation.from_euler(order.upper(), angles_deg, degrees=True).as_matrix()


def matrix_to_euler(order: str, R: np.ndarray) -> np.ndarray:
    """(T, 3) intrinsic angles [deg] in ``order`` for (T, 3, 3) matrices.

    At gimbal lock scipy fixes the third angle to zero; the angles still
    reproduce the matrix, so its warning is silenced.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock")
        return Rotation.from_matrix(R).as_euler(order.upper(), degrees=True)


def matrices_to_quats(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions wxyz (w >= 0)."""
    shape = R.shape[:-2]
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat(scalar_first=True)
    q *= np.where(q[:, :1] < 0.0, -1.0, 1.0)
    return q.reshape(*shape, 4)


def quats_to_matrices(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions wxyz (normalised here) -> (..., 3, 3) matrices."""
    shape = q.shape[:-1]
    return Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix().reshape(*shape, 3, 3)


def frame_from_axes(up: np.ndarray, left: np.ndarray) -> np.ndarray:
    """Right-handed frame with z along ``up`` and y along ``left`` (orthogonalised).

    Args:
        up: (..., 3) approximate up direction.
        left: (..., 3) approximate left direction (its component along ``up`` is removed).

    Returns:
        (..., 3, 3) rotation whose columns are x forward, y left, z up; NaN where
        the axes are degenerate (parallel or zero).
    """
    z = up / np.linalg.norm(up, axis=-1, keepdims=True)
    y = left - np.sum(left * z, axis=-1, keepdims=True) * z
    n = np.linalg.norm(y, axis=-1, keepdims=True)
    y = np.where(n > 1e-9, y / np.where(n > 1e-9, n, 1.0), np.nan)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)
