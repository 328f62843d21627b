"""A wheeled-legged arm robot drawn from its MJCF primitives, posed from the 7 coordinates a RobotState carries.

The G1 is drawn from URDF meshes (:mod:`services.logger.robot_visual`). The TITA-PiPER has no
meshes: its generated MJCF (``models/tita_piper.xml``) holds boxes and cylinders, which Rerun
draws as ``Boxes3D`` / ``Cylinders3D`` (both centred on their pose, a cylinder along its z, the
MuJoCo convention too). Same interface as :class:`~services.logger.robot_visual.RobotVisual`
(``meshes``, ``placements``), plus ``archetype(rgba)`` on each primitive for the static geometry.

Pose: the sim and the solver send seed 002's coordinates ``base_x, base_y, base_z, base_yaw,
arm_j1..3`` (:data:`~services.solver.wbqp_accel.Q_NAMES`), in the world frame the robot started
in. The torso is drawn level at that pose (the balance loop keeps its pitch within a few mrad),
the arm at its three joints with the held ones at their profile values, and the legs by the
balance controller's planar leg IK putting the wheels under the torso at its height. Joints a
message names beyond those (any MJCF joint name) are applied as they are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np
import rerun as rr

from services.solver.wbqp_accel import Q_NAMES
from services.wbc.balance import leg_ik
from shared.robot.wheeled import WheeledRobot, build_wheeled_robot


@dataclass(frozen=True)
class Primitive:
    """One drawn MJCF geom: entity name, MuJoCo type (box/cylinder/sphere), size (3,) as MuJoCo's, RGBA."""

    name: str
    kind: int
    size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    moving: bool = True

    def archetype(self, rgba: tuple[float, float, float, float] | None = None):
        """The Rerun archetype drawing it at its entity's pose (colour ``rgba`` or its own)."""
        colour = [round(255 * c) for c in (rgba or self.rgba)]
        if self.kind == int(mujoco.mjtGeom.mjGEOM_BOX):
            return rr.Boxes3D(half_sizes=[self.size], colors=[colour], fill_mode="solid")
        if self.kind == int(mujoco.mjtGeom.mjGEOM_CYLINDER):
            return rr.Cylinders3D(lengths=[2 * self.size[1]], radii=[self.size[0]], colors=[colour], fill_mode="solid")
        r = self.size[0]
        return rr.Ellipsoids3D(half_sizes=[(r, r, r)], colors=[colour], fill_mode="solid")


#: Geom types drawn (the floor plane is not: the viewer has its own grid).
DRAWN = tuple(int(t) for t in (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_SPHERE))


class WheeledVisual:
    """Primitives of a wheeled profile and their poses for the planner's coordinates.

    Args:
        profile: wheeled profile name or path, or the built robot.
    """

    def __init__(self, profile: str | WheeledRobot = "tita_piper"):
        self.robot = profile if isinstance(profile, WheeledRobot) else build_wheeled_robot(profile)
        m = self.model = self.robot.mj_model
        self.data = mujoco.MjData(m)
        prof = self.robot.profile
        self.meshes: list[Primitive] = []
        self._geoms: list[int] = []
        for g in range(m.ngeom):
            if int(m.geom_type[g]) not in DRAWN or m.geom_rgba[g][3] == 0.0:
                continue  # invisible contact geoms (the wheels' spheres)
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
            size = tuple(float(v) for v in m.geom_size[g])
            self.meshes.append(Primitive(name, int(m.geom_type[g]), size, tuple(float(c) for c in m.geom_rgba[g])))
            self._geoms.append(g)
        self._adr = {m.joint(j).name: int(m.jnt_qposadr[m.joint(j).id]) for j in range(m.njnt)}
        self._arm = dict(zip(Q_NAMES[4:], prof.arm))
        self._wheel_r = float(m.geom_size[m.geom(f"{prof.wheels[0]}_geom").id][0])
        self._shin = float(abs(m.body("left_crus").pos[2]))
        self._legs = [(f"{s}_hip_pitch", f"{s}_knee") for s in ("left", "right")]
        for name, v in prof.held.items():
            self.data.qpos[self._adr[name]] = v

    def placements(self, joints: list[str] | tuple[str, ...], q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Pose of every primitive, in :attr:`meshes` order, for the named coordinates/joints at q.

        Args:
            joints: (k,) names: Q_NAMES entries and/or MJCF joint names. q: (k,) [m, rad].

        Returns:
            [(p (3,) [m], R (3, 3))] in the world frame the robot started in.

        Raises:
            KeyError: a name that is neither.
        """
        d = self.data
        val = dict(zip(joints, np.asarray(q, dtype=float)))
        unknown = [n for n in val if n not in Q_NAMES and n not in self._adr]
        if unknown:
            raise KeyError(f"joints {unknown} not in {self.robot.profile.name}")
        base = [val.get(n, d.qpos[i] if i < 3 else 0.0) for i, n in enumerate(Q_NAMES[:3])]
        yaw = val.get("base_yaw", 0.0)
        d.qpos[0:3] = base
        d.qpos[3:7] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        hip, knee = leg_ik(0.0, -(base[2] - self._wheel_r), self._shin)
        for h, k in self._legs:
            d.qpos[self._adr[h]], d.qpos[self._adr[k]] = hip, knee
        for n, v in val.items():
            if n in self._arm:
                d.qpos[self._adr[self._arm[n]]] = v
            elif n in self._adr:
                d.qpos[self._adr[n]] = v
        mujoco.mj_kinematics(self.model, d)
        return [(d.geom_xpos[g].copy(), d.geom_xmat[g].reshape(3, 3).copy()) for g in self._geoms]
