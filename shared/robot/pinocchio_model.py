"""Pinocchio model of a robot profile, reduced to its controlled joints."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile
from shared.targets import TARGET_NAMES


@dataclass
class RobotModel:
    """Reduced kinematic model: only the controlled joints move.

    Attributes:
        profile: the robot profile it was built from.
        model, data: Pinocchio reduced model and a data buffer.
        joint_names: (n,) controlled joints, solver order (``model`` order).
        lower, upper: (n,) position limits [rad], shrunk by the profile margin.
        vmax: (n,) velocity limits [rad/s] (URDF value capped by the profile).
        amax: (n,) acceleration limits [rad/s^2] (``RobotProfile.joint_acceleration``: the global
            ``max_joint_acceleration``, or per joint the ``[acceleration_limits]`` capped by it).
        q_rest: (n,) rest pose [rad].
        frame_ids: target name -> Pinocchio frame id (the target's position; its orientation too, unless
            ``rotation_ids`` has it).
        rotation_ids: target name -> Pinocchio frame id of its orientation, for the targets whose profile
            ``[orientation_frames]`` names another frame than ``[frames]`` (the G1's wrists).
    """

    profile: RobotProfile
    model: pin.Model
    data: pin.Data
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    vmax: np.ndarray
    amax: np.ndarray
    q_rest: np.ndarray
    frame_ids: dict[str, int]
    rotation_ids: dict[str, int] = field(default_factory=dict)

    @property
    def nq(self) -> int:
        return self.model.nq

    def frame_id(self, target: str) -> int:
        """Pinocchio frame id of a target (``left_wrist``...) or raw frame name."""
        if target in self.frame_ids:
            return self.frame_ids[target]
        if self.model.existFrame(target):
            return self.model.getFrameId(target)
        raise KeyError(f"unknown frame {target!r}; targets: {list(self.frame_ids)}")

    def indices(self, joints) -> list[int]:
        """Positions in q of the named joints that this model controls (others are skipped)."""
        wanted = set(joints)
        return [i for i, n in enumerate(self.joint_names) if n in wanted]

    def forward(self, q: np.ndarray, data: pin.Data | None = None) -> pin.Data:
        """Forward kinematics and frame placements for q (n,) [rad]."""
        data = self.data if data is None else data
        pin.framesForwardKinematics(self.model, data, np.asarray(q, dtype=float))
        return data

    def rotation_id(self, target: str) -> int:
        """Pinocchio frame id of a target's orientation (``frame_id`` unless the profile names another frame)."""
        fid = self.rotation_ids.get(target)
        return self.frame_id(target) if fid is None else fid

    def frame_poses(self, q: np.ndarray, names=TARGET_NAMES) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Poses of targets (or raw frames) in the base frame: name -> (p (3,) [m], R (3, 3)); a target's R is
        that of its orientation frame (``rotation_ids``)."""
        data = self.forward(q)
        out = {}
        for n in names:
            p = data.oMf[self.frame_id(n)].translation
            out[n] = (p.copy(), data.oMf[self.rotation_id(n)].rotation.copy())
        return out

    def clip(self, q: np.ndarray) -> np.ndarray:
        """q clipped into the position limits."""
        return np.clip(q, self.lower, self.upper)

    def random_configurations(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, nq) uniform samples within the position limits."""
        return rng.uniform(self.lower, self.upper, size=(n, self.nq))


def build_robot_model(profile: RobotProfile | str | None = None, with_waist: bool = True) -> RobotModel:
    """Load the profile's URDF with Pinocchio and lock every non-controlled joint at rest.

    Args:
        profile: profile object, name or path (default :data:`DEFAULT_PROFILE`).
        with_waist: control the waist too (17 DoF on the G1) or only the arms (14).
    """
    prof = profile if isinstance(profile, RobotProfile) else load_profile(profile or DEFAULT_PROFILE)
    full = pin.buildModelFromUrdf(str(prof.urdf_path))
    controlled = prof.controlled_joints(with_waist)
    unknown = [j for j in controlled if not full.existJointName(j)]
    if unknown:
        known = [full.names[i] for i in range(1, full.njoints)]
        raise KeyError(f"profile {prof.name}: joints {unknown} not in URDF; URDF joints: {known}")
    q_full = pin.neutral(full)
    for name, val in prof.rest.items():
        if full.existJointName(name):
            q_full[full.joints[full.getJointId(name)].idx_q] = val
    lock = [full.getJointId(full.names[i]) for i in range(1, full.njoints) if full.names[i] not in controlled]
    reduced = pin.buildReducedModel(full, lock, q_full)
    names = tuple(reduced.names[i] for i in range(1, reduced.njoints))
    if set(names) != set(controlled):
        raise RuntimeError(f"reduced model joints {names} differ from controlled {controlled}")
    idx = [reduced.joints[reduced.getJointId(j)].idx_q for j in names]
    lower = reduced.lowerPositionLimit[idx] + prof.limit_margin
    upper = reduced.upperPositionLimit[idx] - prof.limit_margin
    vmax = np.minimum(reduced.velocityLimit[idx], [prof.joint_velocity(j) for j in names])
    amax = np.array([prof.joint_acceleration(j) for j in names])
    q_rest = np.clip(np.array([prof.rest.get(j, 0.0) for j in names]), lower, upper)
    frame_ids = {}
    for target, frame in prof.frames.items():
        if not reduced.existFrame(frame):
            raise KeyError(f"profile {prof.name}: frame {frame!r} for {target} not in URDF")
        frame_ids[target] = reduced.getFrameId(frame)
    rotation_ids = {}
    for target, frame in prof.split_orientation_frames.items():
        if not reduced.existFrame(frame):
            raise KeyError(f"profile {prof.name}: orientation frame {frame!r} for {target} not in URDF")
        rotation_ids[target] = reduced.getFrameId(frame)
    return RobotModel(
        prof, reduced, reduced.createData(), names, lower, upper, vmax, amax, q_rest, frame_ids, rotation_ids
    )
