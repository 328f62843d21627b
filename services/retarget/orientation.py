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

from shared.rotations import cross3, norm3
from shared.targets import SIDES, elbow_of, wrist_of


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


def calibration_posture(
    robot, side: str, wrist: np.ndarray, elbow: np.ndarray | None = None, iters: int = 100
) -> np.ndarray:
    """Robot arm posture for the operator's calibration pose: wrist frame at ``wrist`` (3,) [m].

    The arm IK (:class:`.arm_ik.ArmIk`) over the shoulder and elbow joints from the rest pose, wrist
    joints at zero (the operator calibrates with relaxed, straight wrists). With ``elbow`` (3,) [m] the
    elbow frame is placed too (use a reachable pair, see :mod:`.elbow`); without, the swivel stays near
    the rest pose. Returns q (nq,) [rad] within the limits.
    """
    from services.retarget.arm_ik import ArmIk

    roles = robot.profile.arms[side]
    q0 = robot.q_rest.copy()
    q0[robot.indices(roles.wrist)] = 0.0
    ik = ArmIk(robot, (*roles.shoulder, roles.elbow), q0, damping=1e-6)
    goals = [(ik.frame(wrist_of(side)), np.asarray(wrist, dtype=float), 1.0)]
    if elbow is not None:
        goals.append((ik.frame(elbow_of(side)), np.asarray(elbow, dtype=float), 1.0))
    ik.solve(goals, iters=iters, tol=1e-7)
    return ik.full()


def calibration_orientations(
    robot, rest_targets: dict[str, np.ndarray], elbows: dict[str, np.ndarray] | None = None
) -> dict[str, np.ndarray]:
    """Target -> (3, 3) robot orientation ``W_R_U`` in the calibration posture of each arm.

    Args:
        robot: reduced robot model (arms, waist at rest).
        rest_targets: target -> (3,) robot position [m] of the operator's calibration pose (``U_ps``).
        elbows: side -> (3,) elbow position [m] reachable with that wrist (None: swivel near rest).
    """
    out = {}
    for side in SIDES:
        el = None if elbows is None else elbows.get(side)
        q = calibration_posture(robot, side, rest_targets[wrist_of(side)], el)
        poses = robot.frame_poses(q, names=(wrist_of(side), elbow_of(side)))
        for t, (_p, R) in poses.items():
            out[t] = R.copy()
    return out


def align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation (3, 3) turning direction a (3,) onto direction b (3,)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a, b = a / norm3(a), b / norm3(b)
    axis = cross3(a, b)
    s, c = norm3(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = cross3(a, np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
        return pin.exp3(np.pi * perp / norm3(perp))
    return pin.exp3(axis / s * np.arctan2(s, c))


#: sin of the elbow angle under which an arm counts as straight (its plane is then undefined).
STRAIGHT_SIN = 0.1


def arm_frame(upper: np.ndarray, fore: np.ndarray) -> np.ndarray | None:
    """Forearm frame (3, 3): x along the forearm, z normal to the arm plane (the elbow axis).

    Args:
        upper: (3,) shoulder -> elbow. fore: (3,) elbow -> wrist.

    Returns:
        The frame, or None when the arm is nearly straight (plane undefined).
    """
    fore = np.asarray(fore, dtype=float)
    upper = np.asarray(upper, dtype=float)
    x = fore / norm3(fore)
    z = cross3(upper / norm3(upper), x)
    nz = norm3(z)
    if nz < STRAIGHT_SIN:
        return None
    z /= nz
    return np.array([x, cross3(z, x), z]).T


#: sin of the elbow angle from which the arm plane is trusted fully when blending (:func:`arm_alignment`).
PLANE_SIN = 2.0 * STRAIGHT_SIN


def _plane_weight(upper: np.ndarray, fore: np.ndarray) -> float:
    """0 at an elbow bend of sin STRAIGHT_SIN or less, 1 from PLANE_SIN, smooth (C1) in between."""
    s = norm3(cross3(upper / norm3(upper), fore / norm3(fore)))
    x = min(max((s - STRAIGHT_SIN) / (PLANE_SIN - STRAIGHT_SIN), 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def arm_alignment(
    up_H: np.ndarray, fore_H: np.ndarray, up_U: np.ndarray, fore_U: np.ndarray, blend: bool = False
) -> np.ndarray:
    """Rotation (3, 3) taking the operator's forearm frame onto the robot's (smallest rotation of the
    forearm directions when either arm is straight).

    The switch between the two at STRAIGHT_SIN is a jump: the frames' rotation about the forearm, up to
    ~18 deg in one frame on the real clips (kick_normal, byebye_happy, guide_active). With ``blend`` the
    rotation about the forearm is scaled from none (either arm at STRAIGHT_SIN) to all (both past
    PLANE_SIN), so the result is continuous in the arm directions.
    """
    F_H, F_U = arm_frame(up_H, fore_H), arm_frame(up_U, fore_U)
    if F_H is None or F_U is None:
        return align(fore_H, fore_U)
    A = F_U @ F_H.T
    if not blend:
        return A
    w = min(_plane_weight(up_H, fore_H), _plane_weight(up_U, fore_U))
    if w >= 1.0:
        return A
    A0 = align(fore_H, fore_U)  # A0^T A turns about the operator's forearm only
    return A0 @ pin.exp3(w * pin.log3(A0.T @ A))


class ForearmOrientationMap(OrientationMap):
    """Eq. (4) with the forearms matched: the hand turns *relative to its forearm* as the operator's does.

    Eq. (4) copies the hand's absolute orientation, but the robot's forearm does not point where the
    operator's does (positions are scaled per axis, elbows placed for the robot's arm lengths), so
    the robot wrist joints would have to make up the difference (tens of degrees on real clips).
    Here the operator's hand rotation is first carried by the rotation ``A`` taking the operator's
    forearm frame (forearm direction, arm-plane normal) onto the robot's target one, with the
    calibration's own alignment removed::

        W_R'_U = A' W_R'_H (W_R_H)^-1 A^-1 W_R_U

    At calibration it gives ``W_R_U``; an operator who keeps the wrist still gets the robot hand
    that moves with its forearm.

    Args:
        R_H_rest, R_U_rest: as :class:`OrientationMap` (``R_U_rest``: the robot's calibration posture).
        A_rest: (3, 3) :func:`arm_alignment` at calibration.
    """

    def __init__(self, R_H_rest: np.ndarray, R_U_rest: np.ndarray, A_rest: np.ndarray):
        super().__init__(R_H_rest, R_U_rest)
        self.right = self.R_H_rest.T @ np.asarray(A_rest).T @ self.R_U_rest  # the fixed right-hand factor

    def with_alignment(self, R_H: np.ndarray, A: np.ndarray) -> np.ndarray:
        """Robot target orientation (3, 3) for operator hand R_H (3, 3) and forearm alignment A (3, 3)."""
        return np.asarray(A) @ np.asarray(R_H, dtype=float) @ self.right
