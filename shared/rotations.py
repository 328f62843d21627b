"""Single-rotation conversions shared by every service (quaternions are w, x, y, z).

MuJoCo's C helpers are used rather than ``pin.Quaternion``: constructing Pinocchio
quaternions from matrices leaked memory in the long-running retarget service (soak test,
8.5 MB/min at 1 kHz), and these run once per target per frame.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (4,) w, x, y, z with w >= 0 from a rotation matrix (3, 3)."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).ravel())
    return -q if q[0] < 0.0 else q


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a quaternion (4,) w, x, y, z (normalised here)."""
    qn = np.array(q, dtype=float)
    # np.linalg.norm's own steps for a vector (the same bits) without its Python overhead: the solver converts
    # every target of every message.
    norm = math.sqrt(qn.dot(qn))
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f"quaternion {q!r} has no rotation (norm {norm})")
    qn /= norm
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, qn)
    return R.reshape(3, 3)


def quats_to_matrices(Q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of quaternions (n, 4) w, x, y, z, each normalised in place first.

    The batch form of :func:`quat_to_matrix` for per-frame paths (no checks: the quaternions must
    have a norm, e.g. validated when their message was decoded).
    """
    R = np.empty((len(Q), 3, 3))
    for q, r in zip(Q, R, strict=True):
        mujoco.mju_normalize4(q)
        mujoco.mju_quat2Mat(r.reshape(9), q)
    return R


def matrices_to_quats(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) w, x, y, z with w >= 0 of rotation matrices (n, 3, 3) (C-contiguous).

    The batch form of :func:`matrix_to_quat`.
    """
    Q = np.empty((len(R), 4))
    for q, r in zip(Q, R, strict=True):
        mujoco.mju_mat2Quat(q, r.reshape(9))
        if q[0] < 0.0:
            q *= -1.0
    return Q


def quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (4,) x, y, z, w (Rerun's order) of a rotation matrix (3, 3)."""
    return np.roll(matrix_to_quat(R), -1)


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product (3,) of two 3-vectors.

    ``np.cross`` costs ~20 us per call on 3-vectors (axis handling); the retargeter makes
    several per target per frame at up to 1 kHz.
    """
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def norm3(a: np.ndarray) -> float:
    """Euclidean norm of a 3-vector (cheaper than ``np.linalg.norm`` at this size)."""
    return math.sqrt(float(a @ a))
