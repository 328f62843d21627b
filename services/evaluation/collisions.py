"""Self-collision figures of an evaluation run: arms against torso, pelvis, head and the other arm.

The geometry is MuJoCo's (the URDF collision meshes). Pairs are every collision geom of an arm's
forearm side (the elbow link and everything below it: the upper-arm links sit against the torso by
design and their meshes overlap it at rest) against every collision geom of the trunk (pelvis,
waist, torso, head: every body that is neither an arm nor a leg) and of the other arm.

* ``penetrating(data)``: whether any such pair is in contact with negative distance in a simulated
  state (MuJoCo's own contacts after ``mj_step``).
* ``clearance(q)``: the smallest signed distance [m] over the pairs for joint positions q, from
  ``mj_geomDistance`` (negative: penetration depth).
"""

from __future__ import annotations

import mujoco
import numpy as np

from shared.robot.mujoco_model import MujocoRobot, build_mujoco_robot
from shared.robot.profile import RobotProfile

#: Body name parts of the legs (not part of the self-collision set of the issue: arms vs trunk/arms).
LEG_PARTS = ("hip", "knee", "ankle")
#: Distance beyond which mj_geomDistance stops looking [m]: clearances are reported up to this.
DIST_MAX = 0.2


def _subtree(model: mujoco.MjModel, root: int) -> set[int]:
    out = {root}
    for b in range(model.nbody):
        p = b
        while p > 0:
            if p == root:
                out.add(b)
                break
            p = model.body_parentid[p]
    return out


class SelfCollision:
    """Arm/trunk and arm/arm pairs of a robot's MuJoCo model.

    Args:
        profile: robot profile.
        joint_names: joints ``q`` is given for (the Pinocchio model's order).
    """

    def __init__(self, profile: RobotProfile, joint_names: tuple[str, ...]):
        self.robot: MujocoRobot = build_mujoco_robot(profile, joint_names=joint_names)
        m = self.robot.model
        self.model = m
        self.data = mujoco.MjData(m)
        self.data.qpos[:] = self.robot.data.qpos
        arms = {}
        for side in ("left", "right"):
            elbow = m.body(profile.frames[f"{side}_elbow"]).id
            shoulder = m.body(profile.frames.get(f"{side}_shoulder", f"{side}_shoulder_pitch_link")).id
            arms[side] = (_subtree(m, elbow), _subtree(m, shoulder))
        all_arm = arms["left"][1] | arms["right"][1]
        trunk = {b for b in range(1, m.nbody) if b not in all_arm and not any(k in m.body(b).name for k in LEG_PARTS)}

        def geoms(bodies: set[int]) -> list[int]:
            hit = (m.geom_contype != 0) | (m.geom_conaffinity != 0)
            return [g for g in range(m.ngeom) if m.geom_bodyid[g] in bodies and hit[g]]

        pairs = set()
        for side, other in (("left", "right"), ("right", "left")):
            fore = geoms(arms[side][0])
            for g in fore:
                for h in geoms(trunk) + geoms(arms[other][1]):
                    pairs.add((min(g, h), max(g, h)))
        self.pairs = np.array(sorted(pairs), dtype=int).reshape(-1, 2)
        self._pairset = {tuple(p) for p in self.pairs}
        self._fromto = np.zeros(6)

    def penetrating(self, data: mujoco.MjData) -> bool:
        """Whether a simulated state has a contact of negative distance between a pair."""
        for i in range(data.ncon):
            c = data.contact[i]
            if c.dist < 0 and (min(c.geom1, c.geom2), max(c.geom1, c.geom2)) in self._pairset:
                return True
        return False

    def clearance(self, q: np.ndarray) -> float:
        """Smallest signed distance [m] over the pairs for joints q (n,) [rad] (capped at DIST_MAX)."""
        d = self.data
        d.qpos[self.robot.qpos_idx] = q
        mujoco.mj_kinematics(self.model, d)
        best = DIST_MAX
        for g, h in self.pairs:
            best = min(best, mujoco.mj_geomDistance(self.model, d, int(g), int(h), DIST_MAX, self._fromto))
        return float(best)
