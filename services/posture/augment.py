"""Physically consistent augmentation of elbow-kind samples: whole arms turned rigidly about the shoulder.

A sample of the ``elbow`` kind is a hand pose ``(Q, p)`` (the encoder's inputs, :mod:`.features`) and the
operator's elbow ``e`` (3,) [m], all in the robot base frame. Turning the whole arm by a rotation ``R_a``
about the robot's shoulder centre ``c`` gives another arm of the same proportions: ``p' = c + R_a (p - c)``,
``e' = c + R_a (e - c)`` (upper-arm and forearm lengths kept, so ``e'`` is still an elbow that reaches
``p'``), and the hand's orientation turned with it, ``R(Q') = R_a R(Q)``. Rotations are small yaw (about
the base z axis) and pitch (about its y axis) angles, drawn uniformly: an operator's gesture done a little
more to the side, higher or lower. A reach change (:func:`scale_reach`) moves the wrist along the
shoulder-wrist axis and puts the elbow back on the circle of elbows that reach it, on the same side.
Training only: the real-time path never sees this module.
"""

from __future__ import annotations

import numpy as np

from services.retarget.elbow import elbow_circle
from shared.rotations import quats_to_matrices


def yaw_pitch_rotations(
    rng: np.random.Generator, n: int, max_deg: float, max_pitch_deg: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """n rotations ``R_a = R_z(yaw) R_y(pitch)``, yaw uniform in ±max_deg, pitch in ±max_pitch_deg [deg]
    (default: max_deg; 0: turns about the vertical only, which keep the arm's pose against gravity).

    Returns:
        (quaternions (n, 4) wxyz with w > 0, matrices (n, 3, 3)) of the same rotations.
    """
    pitch = max_deg if max_pitch_deg is None else max_pitch_deg
    half = np.deg2rad(rng.uniform(-1.0, 1.0, (2, n)) * np.array([[max_deg], [pitch]])) / 2.0
    cz, sz = np.cos(half[0]), np.sin(half[0])
    cy, sy = np.cos(half[1]), np.sin(half[1])
    # q_z ⊗ q_y with q_z = (cz, 0, 0, sz), q_y = (cy, 0, sy, 0)
    q = np.stack([cz * cy, -sz * sy, cz * sy, sz * cy], axis=1)
    return q, quats_to_matrices(q.copy())


def _quat_products(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a ⊗ b (n, 4) of quaternion rows (n, 4) (the batch form of ``kinematics.quaternion.qmul``)."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=1,
    )


def turn_arms(
    hand: np.ndarray, elbow: np.ndarray, centre: np.ndarray, q_rot: np.ndarray, R_rot: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Hand poses (n, 7) ``(Q wxyz, p)`` and elbows (n, 3) [m] turned by per-sample rotations about ``centre`` (3,).

    ``Q' = q_rot ⊗ Q`` keeps the sign convention of the inputs: with ``q_rot``'s w > 0 (a turn below 180°),
    ``Q'·Q = w_rot > 0``, so samples away from the quaternion seam stay on its side (:func:`.features.canonical_quat`).

    Args:
        q_rot, R_rot: (n, 4), (n, 3, 3) the rotations (:func:`yaw_pitch_rotations`).
    """
    Q = _quat_products(q_rot, hand[:, :4])
    p = centre + np.einsum("nij,nj->ni", R_rot, hand[:, 4:7] - centre)
    e = centre + np.einsum("nij,nj->ni", R_rot, elbow - centre)
    return np.concatenate([Q, p], axis=1), e


def scale_reach(
    hand: np.ndarray, elbow: np.ndarray, centre: np.ndarray, upper: float, fore: float, scale: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Hand poses (n, 7) and elbows (n, 3) [m] with the shoulder-wrist distance times ``scale`` (n,).

    The wrist moves along the shoulder-wrist axis ``u``; the elbow goes onto the circle of elbows that reach
    the new wrist (``retarget.elbow.elbow_circle``: upper-arm length ``upper`` from ``centre``, forearm
    ``fore`` from the wrist, distances clamped into the lengths' range) in the direction its offset from the
    axis had (the same swivel angle). The hand's orientation is kept.
    """
    v = hand[:, 4:7] - centre
    d = np.linalg.norm(v, axis=1)
    u = v / np.maximum(d, 1e-9)[:, None]
    off = elbow - centre
    perp = off - np.einsum("ni,ni->n", off, u)[:, None] * u
    perp /= np.maximum(np.linalg.norm(perp, axis=1), 1e-9)[:, None]
    x, r = np.array([elbow_circle(upper, fore, float(di)) for di in d * scale]).T
    out = hand.copy()
    out[:, 4:7] = centre + (d * scale)[:, None] * u
    return out, centre + x[:, None] * u + r[:, None] * perp
