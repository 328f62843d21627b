"""The robot's visual meshes and their placements from Pinocchio forward kinematics.

The profile's URDF is loaded with its VISUAL geometry (one STL per link on the G1).
Placements are in the base (pelvis) frame, which Pinocchio's URDF model uses as its
world since the pelvis is the root link. Joints a message does not name stay at the
profile's rest pose; geometries no controlled joint can move are reported as static
so the logger writes them once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile


@dataclass(frozen=True)
class VisualMesh:
    """One visual geometry: entity name, mesh file, RGBA colour (4,), moves with q or not."""

    name: str
    path: Path
    rgba: tuple[float, float, float, float]
    moving: bool


class RobotVisual:
    """Meshes of a robot profile and their poses for given joint positions.

    Args:
        profile: robot profile (object, name or path; default G1).
    """

    def __init__(self, profile: RobotProfile | str | None = None):
        prof = profile if isinstance(profile, RobotProfile) else load_profile(profile or DEFAULT_PROFILE)
        self.profile = prof
        self.model = pin.buildModelFromUrdf(str(prof.urdf_path))
        self.geom = pin.buildGeomFromUrdf(
            self.model, str(prof.urdf_path), pin.GeometryType.VISUAL, package_dirs=[str(d) for d in prof.package_dirs]
        )
        self.data = self.model.createData()
        self.geom_data = pin.GeometryData(self.geom)
        self.q_rest = pin.neutral(self.model)
        for name, val in prof.rest.items():
            if self.model.existJointName(name):
                self.q_rest[self.model.joints[self.model.getJointId(name)].idx_q] = val
        controlled = {self.model.getJointId(n) for n in prof.controlled_joints(True) if self.model.existJointName(n)}
        self.meshes: list[VisualMesh] = []
        for go in self.geom.geometryObjects:
            moving = any(j in controlled for j in self.model.supports[go.parentJoint])
            rgba = tuple(float(c) for c in go.meshColor)
            self.meshes.append(VisualMesh(go.name, Path(go.meshPath), rgba, moving))
        self._qidx: dict[tuple[str, ...], np.ndarray] = {}

    def _indices(self, joints: tuple[str, ...]) -> np.ndarray:
        idx = self._qidx.get(joints)
        if idx is None:
            unknown = [j for j in joints if not self.model.existJointName(j)]
            if unknown:
                raise KeyError(f"joints {unknown} not in {self.profile.name}")
            idx = np.array([self.model.joints[self.model.getJointId(j)].idx_q for j in joints], dtype=int)
            self._qidx[joints] = idx
        return idx

    def placements(self, joints: list[str] | tuple[str, ...], q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Pose of every mesh, in :attr:`meshes` order, for the named joints at q.

        Args:
            joints: (k,) joint names. q: (k,) positions [rad].

        Returns:
            [(p (3,) [m], R (3, 3))] in the base frame.
        """
        qf = self.q_rest.copy()
        qf[self._indices(tuple(joints))] = q
        pin.forwardKinematics(self.model, self.data, qf)
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.geom_data)
        return [(m.translation.copy(), m.rotation.copy()) for m in self.geom_data.oMg]
