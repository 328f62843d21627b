"""Robot configuration: joint positions plus the kinematics computed from them.

A :class:`Configuration` wraps a :class:`~shared.robot.pinocchio_model.RobotModel`
(reduced to the controlled joints, base frame = pelvis) and its own Pinocchio
data. :meth:`Configuration.update` runs one ``computeJointJacobians`` and one
``updateFramePlacements``; every frame pose and Jacobian afterwards is read from
that data once per update and cached (several tasks share a frame: the wrist
position and orientation tasks, the gain shaping), so building all tasks of a
tick costs one kinematics pass and one read per frame.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from shared.kinematics.exceptions import InvalidConfigurationError, InvalidFrameError
from shared.robot.pinocchio_model import RobotModel

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class Configuration:
    """Joint configuration q (n,) [rad] of a reduced robot model and its kinematics.

    Args:
        robot: reduced model (``build_robot_model``).
        q: initial configuration (n,) [rad]; the rest pose when None.
    """

    def __init__(self, robot: RobotModel, q: np.ndarray | None = None):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.nv = robot.model.nv
        self.q = np.array(robot.q_rest if q is None else q, dtype=float)
        self._frame_cache: dict[str, int] = {}
        #: per frame or target name, read once per update: (p (3,), R (3, 3)) and the (6, n) Jacobian
        self._poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._jacobians: dict[str, np.ndarray] = {}
        self.update(self.q)

    def frame_id(self, name: str) -> int:
        """Pinocchio frame id of a target name (``left_wrist``...) or raw frame name."""
        fid = self._frame_cache.get(name)
        if fid is None:
            try:
                fid = self.robot.frame_id(name)
            except KeyError:
                known = list(self.robot.frame_ids) + [f.name for f in self.model.frames]
                raise InvalidFrameError(name, known) from None
            self._frame_cache[name] = fid
        return fid

    def update(self, q: np.ndarray | None = None) -> None:
        """Set q (n,) [rad] (keep the current one when None) and recompute joint Jacobians and frame poses."""
        if q is not None:
            if q.shape != (self.nv,):
                raise InvalidConfigurationError(f"q has shape {q.shape}, expected ({self.nv},)")
            self.q[:] = q
        pin.computeJointJacobians(self.model, self.data, self.q)
        pin.updateFramePlacements(self.model, self.data)
        self._poses.clear()
        self._jacobians.clear()

    def get_frame_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Pose of a frame in the base (pelvis) frame; a target's rotation is that of its orientation frame
        (``RobotModel.rotation_ids``: the G1's wrist position is the pitch axis, its orientation the hand's).

        Returns:
            p (3,) [m] and R (3, 3), read once per :meth:`update` and shared by every caller until the
            next one (do not write into them).
        """
        pose = self._poses.get(name)
        if pose is None:
            # One conversion of the 4x4 placement (two for translation and rotation cost twice as much).
            H = self.data.oMf[self.frame_id(name)].homogeneous
            rid = self.robot.rotation_ids.get(name)
            pose = self._poses[name] = (H[:3, 3], H[:3, :3] if rid is None else self.data.oMf[rid].rotation)
        return pose

    def get_frame_jacobian(self, name: str) -> np.ndarray:
        """(6, n) Jacobian of a frame, LOCAL_WORLD_ALIGNED: rows [linear (3) [m/rad]; angular (3) [rad/rad]].

        The linear rows give the velocity of the frame origin expressed in the base
        frame; the angular rows the angular velocity in the base frame (of a target's orientation frame, as
        :meth:`get_frame_pose`). Read once per :meth:`update` and shared by every caller until the next one
        (do not write into it).
        """
        J = self._jacobians.get(name)
        if J is None:
            J = pin.getFrameJacobian(self.model, self.data, self.frame_id(name), _LWA)
            rid = self.robot.rotation_ids.get(name)
            if rid is not None:
                J[3:] = pin.getFrameJacobian(self.model, self.data, rid, _LWA)[3:]
            self._jacobians[name] = J
        return J

    def integrate(self, v: np.ndarray, dt: float) -> np.ndarray:
        """q + v dt on the configuration manifold: (n,) [rad] for v (n,) [rad/s], dt [s]."""
        return pin.integrate(self.model, self.q, v * dt)

    def integrate_inplace(self, v: np.ndarray, dt: float) -> None:
        """Integrate v (n,) [rad/s] over dt [s] and update the kinematics."""
        self.update(self.integrate(v, dt))
