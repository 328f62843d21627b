"""The sagittal mirror: of points, orientations, side names and a robot's arm joints.

Frames are the pelvis / robot base frame (x forward, y left, z up); the mirror reflects through its
x-z plane, ``M = diag(1, -1, 1)``, and swaps the two sides. Used where a side is built from the other
(a one-armed calibration, mirrored posture demonstrations), where the two arms must stay mirror images
(the workspace of a symmetric robot), and to make held-out motion from a recorded clip
(``services.ingest.variants``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from shared.targets import SIDES

if TYPE_CHECKING:  # the point and orientation mirrors need no robot model (nor Pinocchio)
    from shared.robot.pinocchio_model import RobotModel

#: (3, 3) reflection through the sagittal (x-z) plane.
MIRROR = np.diag([1.0, -1.0, 1.0])


def mirror_points(p: np.ndarray) -> np.ndarray:
    """(..., 3) positions [m] reflected through the x-z plane (y negated); a new array."""
    return np.asarray(p, dtype=float) * np.array([1.0, -1.0, 1.0])


def mirror_quats(q: np.ndarray) -> np.ndarray:
    """(..., 4) wxyz orientations reflected through the x-z plane: ``R' = M R M``; a new array.

    A rotation's axis is an axial vector: the reflection maps it to ``det(M) M a = (-ax, ay, -az)`` and
    keeps the angle, so ``(w, x, y, z) -> (w, -x, y, -z)``.
    """
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, 1.0, -1.0])


def other_side(side: str) -> str:
    """``"left"`` -> ``"right"`` and back.

    Raises:
        ValueError: not a side name.
    """
    if side not in SIDES:
        raise ValueError(f"unknown side {side!r} (expected one of {SIDES})")
    return SIDES[1 - SIDES.index(side)]


def swap_side(name: str) -> str:
    """A sided name's other side (``left_wrist`` -> ``right_wrist``); names of the midline unchanged."""
    for side in SIDES:
        if name.startswith(f"{side}_"):
            return f"{other_side(side)}_{name[len(side) + 1 :]}"
    return name


def arm_joints(robot: RobotModel, side: str) -> np.ndarray:
    """Indices (n_arm,) of the side's arm joints in the model's joint order (profile ``[arms.<side>]``)."""
    return np.array([robot.joint_names.index(n) for n in robot.profile.arms[side].joints])


def mirror_signs(robot: RobotModel, trials: int = 3, tol: float = 1e-3) -> np.ndarray:
    """Per arm joint (n_arm,): the sign that maps a left-arm angle onto the mirrored right-arm angle.

    Found on the model, not assumed: the sign vector for which the right arm at ``sign * q_left`` puts
    its elbow and wrist at the mirror image of the left arm's (and the wrist orientation at ``M R M``)
    for random postures.

    Raises:
        ValueError: the robot's arms are not mirror images of each other (no sign vector fits).
    """
    left, right = arm_joints(robot, "left"), arm_joints(robot, "right")
    rng = np.random.default_rng(0)
    postures = [rng.uniform(-0.8, 0.8, len(left)) for _ in range(trials)]
    for bits in range(2 ** len(left)):
        sign = np.array([1.0 if (bits >> k) & 1 else -1.0 for k in range(len(left))])
        ok = True
        for ql in postures:
            q = robot.q_rest.copy()
            q[left], q[right] = ql, sign * ql
            P = robot.frame_poses(q)
            for f in ("elbow", "wrist"):
                (pl, Rl), (pr, Rr) = P[f"left_{f}"], P[f"right_{f}"]
                if np.linalg.norm(MIRROR @ pl - pr) > tol or np.linalg.norm(MIRROR @ Rl @ MIRROR - Rr) > tol:
                    ok = False
                    break
            if not ok:
                break
        if ok:
            return sign
    raise ValueError(f"{robot.profile.name}: the arms are not mirror images (no joint sign map found)")


def mirrored_arms(robot: RobotModel, tol: float = 1e-6) -> np.ndarray | None:
    """The joint signs of :func:`mirror_signs` when the arms are mirror images in their kinematics *and* their
    joint ranges (each right-arm range is the mirrored left-arm range within ``tol`` [rad]), else None.

    Then the right arm's reachable set is the mirror image of the left's, joint samples and all.
    """
    try:
        sign = mirror_signs(robot)
    except ValueError:
        return None
    left, right = arm_joints(robot, "left"), arm_joints(robot, "right")
    lo_m = np.minimum(sign * robot.lower[left], sign * robot.upper[left])
    hi_m = np.maximum(sign * robot.lower[left], sign * robot.upper[left])
    if np.allclose(lo_m, robot.lower[right], atol=tol) and np.allclose(hi_m, robot.upper[right], atol=tol):
        return sign
    return None
