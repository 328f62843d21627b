"""MuJoCo model of a robot profile, built from the same URDF as Pinocchio.

MuJoCo's URDF importer cannot resolve ``package://`` URIs, so the URDF text is
rewritten with absolute mesh paths, static bodies are kept (the target frames
are fixed links), and position servos are added to every joint through
``MjSpec``. The pelvis has no free joint in the URDF, so it is welded to the
world: the base is fixed, legs are held at rest by their servos.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import mujoco
import numpy as np

from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile

_MESH_RE = re.compile(r'filename="(package://[^"]+)"')


def urdf_for_mujoco(profile: RobotProfile) -> str:
    text = profile.urdf_path.read_text()
    text = _MESH_RE.sub(lambda m: f'filename="{profile.mesh_uri_to_path(m.group(1))}"', text)
    compiler = (
        '<mujoco><compiler fusestatic="false" discardvisual="false" strippath="false" '
        'balanceinertia="true" angle="radian"/></mujoco>'
    )
    return re.sub(r"(<robot[^>]*>)", r"\1" + compiler, text, count=1)


@dataclass
class MujocoRobot:
    """Compiled MuJoCo model plus index maps for the controlled joints.

    Attributes:
        model, data: MuJoCo model and data.
        joint_names: (n,) controlled joints (same order as the Pinocchio model).
        qpos_idx, dof_idx, act_idx: (n,) indices of those joints.
        body_ids: target name -> body id of its frame (position; orientation too unless in ``rotation_body_ids``).
        rotation_body_ids: target name -> body id of its orientation frame, where the profile's
            ``[orientation_frames]`` names another one (as ``RobotModel.rotation_ids``).
    """

    profile: RobotProfile
    model: mujoco.MjModel
    data: mujoco.MjData
    joint_names: tuple[str, ...]
    qpos_idx: np.ndarray
    dof_idx: np.ndarray
    act_idx: np.ndarray
    body_ids: dict[str, int]
    rotation_body_ids: dict[str, int] = field(default_factory=dict)

    def set_q(self, q: np.ndarray) -> None:
        """Set controlled joint positions (n,) [rad] and servo targets, then run kinematics."""
        self.data.qpos[self.qpos_idx] = q
        self.data.ctrl[self.act_idx] = q
        mujoco.mj_kinematics(self.model, self.data)

    def frame_pose(self, target: str) -> tuple[np.ndarray, np.ndarray]:
        """(p (3,) [m], R (3, 3)) of a target frame in the base (pelvis) frame."""
        base = self.body_ids["__base__"]
        bid = self.body_ids[target]
        Rb = self.data.xmat[base].reshape(3, 3)
        pb = self.data.xpos[base]
        R = self.data.xmat[self.rotation_body_ids.get(target, bid)].reshape(3, 3)
        return Rb.T @ (self.data.xpos[bid] - pb), Rb.T @ R


def _exclude_near_contacts(spec: mujoco.MjSpec, hops: int) -> None:
    """Exclude contacts between rigid groups at most ``hops`` joints apart up the tree.

    A rigid group is a body with a joint plus every body welded to it (fixed URDF
    joints such as the torso's logo link); groups count as one link.
    """
    bodies = [b for b in spec.bodies if b.name and b.name != "world"]

    def group(b):
        while len(b.joints) == 0 and b.parent is not None and b.parent.name not in ("", "world"):
            b = b.parent
        return b.name

    members: dict[str, list[str]] = {}
    for b in bodies:
        members.setdefault(group(b), []).append(b.name)
    by_name = {b.name: b for b in bodies}
    pairs = set()
    for root in members:
        anc = by_name[root].parent
        for _ in range(hops):
            if anc is None or anc.name in ("", "world"):
                break
            up = group(anc)
            pairs.update((a, b) for a in members[up] for b in members[root])
            anc = by_name[up].parent
    for a, b in sorted(pairs):
        exclude = spec.add_exclude()
        exclude.bodyname1, exclude.bodyname2 = a, b


def build_mujoco_robot(
    profile: RobotProfile | str | None = None,
    joint_names: tuple[str, ...] | None = None,
    timestep: float = 0.001,
    gravity_compensation: bool = False,
    contact_exclude_hops: int = 1,
) -> MujocoRobot:
    """Compile the profile's URDF into MuJoCo with position servos on every joint.

    Args:
        profile: profile object, name or path.
        joint_names: controlled joints, in the order the caller uses
            (default: the profile's 17 with the waist).
        timestep: physics step [s].
        gravity_compensation: motors cancel gravity: every body gets ``gravcomp = 1``
            routed through the joint actuators (``actgravcomp``, so the effort limits
            still apply). Must be set in the spec: MuJoCo sizes it at compile time.
        contact_exclude_hops: no contacts between a body and its ancestors up to this many
            joints up the tree. 1 is MuJoCo's own parent-child filter; the URDF collision
            meshes of a shoulder overlap the torso two and three links up, so a value of 3
            keeps those spurious contacts out while arms still collide with torso and legs.
    """
    prof = profile if isinstance(profile, RobotProfile) else load_profile(profile or DEFAULT_PROFILE)
    spec = mujoco.MjSpec.from_string(urdf_for_mujoco(prof))
    spec.option.timestep = timestep
    kp = prof.actuators.get("kp", 400.0)
    kv = prof.actuators.get("kv", 20.0)
    armature = prof.actuators.get("armature", 0.01)
    if gravity_compensation:
        for body in spec.bodies:
            body.gravcomp = 1.0
    for joint in spec.joints:
        joint.armature = armature
        if gravity_compensation:
            joint.actgravcomp = True
        act = spec.add_actuator()
        act.name = joint.name
        act.target = joint.name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_position(kp=kp, kv=kv)
        if joint.limited:
            act.ctrlrange = joint.range
            act.ctrllimited = True
    if contact_exclude_hops > 1:
        _exclude_near_contacts(spec, contact_exclude_hops)
    model = spec.compile()
    data = mujoco.MjData(model)
    names = tuple(joint_names or prof.controlled_joints(True))
    qpos_idx = np.array([model.jnt_qposadr[model.joint(n).id] for n in names])
    dof_idx = np.array([model.jnt_dofadr[model.joint(n).id] for n in names])
    act_idx = np.array([model.actuator(n).id for n in names])
    body_ids = {t: model.body(f).id for t, f in prof.frames.items()}
    body_ids["__base__"] = model.body(prof.base_frame).id
    rotation_body_ids = {t: model.body(f).id for t, f in prof.split_orientation_frames.items()}
    # Every joint (legs too) starts, and is held, at the rest pose.
    for j in range(model.njnt):
        name = model.joint(j).name
        val = prof.rest.get(name, 0.0)
        data.qpos[model.jnt_qposadr[j]] = val
        data.ctrl[model.actuator(name).id] = val
    mujoco.mj_forward(model, data)
    return MujocoRobot(prof, model, data, names, qpos_idx, dof_idx, act_idx, body_ids, rotation_body_ids)
