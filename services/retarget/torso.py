"""The operator's torso rotation as the robot's waist joint angles (issue 12): what the robot's waist would be if
it turned its torso as the operator turned their chest. ``mimic eval`` scores every algorithm's waist against it
(``waist_vs_operator_deg``): a strict HQP uses the waist freely for the hands, and nothing else tells how far the
robot's torso strays from the operator's.

Frames: the operator's bones are in their pelvis frame (x forward, y left, z up; ``HumanFrame.bones``), so a
chest orientation ``R_c`` (3, 3) is already relative to the pelvis. Against the chest at the calibration (rest)
frame ``R_c0``, the chest's rotation since the rest, expressed in the pelvis frame, is

    D = R_c R_c0^T.

(A spatial rotation: it does not depend on the rig's own bone axes, which cancel.) The robot's waist is a serial
chain of revolute joints; with its spatial axes ``a_1, a_2, a_3`` (base frame, unit, at the waist's rest, in the
chain's order: G1 yaw z, roll x, pitch y) the torso link turns by (product of exponentials, seed 003)

    R_t(q_rest + theta) R_t(q_rest)^T = Rot(a_1, theta_1) Rot(a_2, theta_2) Rot(a_3, theta_3).

For mutually orthogonal axes this is a Tait-Bryan split, solved exactly: with ``e = (a_1 x a_2) . a_3`` (+-1),

    theta_2 = asin(e a_1^T D a_3),
    theta_1 = atan2(-e a_2^T D a_3, a_3^T D a_3),
    theta_3 = atan2(-e a_1^T D a_2, a_1^T D a_1),

the middle angle in [-90, 90] deg. The waist angles are ``q_rest + theta`` clipped into the joints' ranges
(``RobotModel.lower/upper``: the URDF's less the profile's ``limit_margin``, what the solver keeps). Angles [rad].
(Written by a session-12 helper on branch h12w, where it also posed the trunk push; only the map is kept.)
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from shared.messages import HumanFrame
from shared.robot.pinocchio_model import RobotModel, build_robot_model
from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile
from shared.rotations import quat_to_matrix

#: The operator's chest bone (canonical, ``shared.messages.HUMAN_BONES``).
CHEST = "chest"
#: Largest |a_i . a_j| [-] accepted as orthogonal waist axes (the exact split needs them orthogonal).
ORTHO_TOL = 1e-6


def chest_rotation(frame: HumanFrame) -> np.ndarray | None:
    """The operator's chest orientation (3, 3) in their pelvis frame, None when the frame has no measured one
    (no chest bone, an invalid one, or a marker-only source whose orientations are placeholders)."""
    bone = frame.bones.get(CHEST)
    if bone is None or not bone.valid or not frame.oriented:
        return None
    return quat_to_matrix(np.asarray(bone.q, dtype=float))


class WaistMap:
    """The operator's chest rotation since the rest -> the robot's waist joint angles that turn its torso alike.

    Args:
        robot: a model *with* the waist joints (default: built from ``profile`` with the waist; cached).
        profile: the robot profile, when ``robot`` is not given.

    Attributes:
        joints: the waist joint names, chain order (profile ``waist``).
        axes: (3, 3) rows = their unit spatial axes at the waist's rest (base frame).
        lower, upper, rest: (3,) [rad] the joints' clipped ranges and rest angles.

    Raises:
        ValueError: the profile has no waist, not three waist joints, or their axes are not orthogonal.
    """

    def __init__(self, robot: RobotModel | None = None, profile: RobotProfile | str | None = None):
        robot = robot if robot is not None else _waist_model(profile)
        prof = robot.profile
        if len(prof.waist) != 3:
            raise ValueError(f"robot profile {prof.name}: waist {list(prof.waist)}; the split needs 3 joints")
        missing = [j for j in prof.waist if j not in robot.joint_names]
        if missing:
            raise ValueError(f"robot model lacks the waist joints {missing} (build it with the waist)")
        self.robot = robot
        self.joints = tuple(prof.waist)
        self._idx = np.array(robot.indices(self.joints))
        m, d = robot.model, robot.model.createData()
        last = m.getJointId(self.joints[-1])
        pin.computeJointJacobians(m, d, robot.q_rest)
        # angular rows of the last waist joint's Jacobian, world-aligned: each waist column is that joint's
        # spatial axis at the rest (the product of exponentials around q_rest)
        J = pin.getJointJacobian(m, d, last, pin.LOCAL_WORLD_ALIGNED)[3:]
        cols = [m.joints[m.getJointId(j)].idx_v for j in self.joints]
        axes = J[:, cols].T
        axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
        gram = axes @ axes.T - np.eye(3)
        if np.abs(gram).max() > ORTHO_TOL:
            raise ValueError(f"waist axes {axes.round(4).tolist()} are not orthogonal: no exact split")
        self.axes = axes
        self._e = float(np.cross(axes[0], axes[1]) @ axes[2])
        self.lower = robot.lower[self._idx].copy()
        self.upper = robot.upper[self._idx].copy()
        self.rest = robot.q_rest[self._idx].copy()

    def split(self, D: np.ndarray) -> np.ndarray:
        """(3,) [rad] the angles theta about :attr:`axes` (chain order) whose product is the rotation D (3, 3);
        unclipped, the middle one in [-pi/2, pi/2]."""
        a1, a2, a3 = self.axes
        e = self._e
        s2 = float(np.clip(e * (a1 @ D @ a3), -1.0, 1.0))
        t1 = math.atan2(-e * (a2 @ D @ a3), a3 @ D @ a3)
        t3 = math.atan2(-e * (a1 @ D @ a2), a1 @ D @ a1)
        return np.array([t1, math.asin(s2), t3])

    def angles(self, R_chest: np.ndarray, R_rest: np.ndarray) -> np.ndarray:
        """(3,) [rad] the waist joint angles (``q_rest + theta``), unclipped, for the operator's chest at R_chest
        (3, 3) against its rest R_rest (3, 3), both in the operator's pelvis frame."""
        return self.rest + self.split(R_chest @ R_rest.T)

    def __call__(self, R_chest: np.ndarray, R_rest: np.ndarray) -> np.ndarray:
        """(3,) [rad] :meth:`angles` clipped into the joints' ranges."""
        return np.clip(self.angles(R_chest, R_rest), self.lower, self.upper)

    def rotation(self, q_waist: np.ndarray) -> np.ndarray:
        """(3, 3) the torso's rotation since the rest (base frame) at the waist angles q_waist (3,) [rad]."""
        R = np.eye(3)
        for a, t in zip(self.axes, np.asarray(q_waist, dtype=float) - self.rest, strict=True):
            R = R @ pin.exp3(a * t)
        return R


#: profile source -> its model with the waist (built once per process)
_MODELS: dict[str, RobotModel] = {}


def _waist_model(profile: RobotProfile | str | None) -> RobotModel:
    """The profile's model with the waist joints (cached)."""
    prof = profile if isinstance(profile, RobotProfile) else load_profile(profile or DEFAULT_PROFILE)
    key = str(prof.source)
    if key not in _MODELS:
        _MODELS[key] = build_robot_model(prof, with_waist=True)
    return _MODELS[key]
