"""Per-joint acceleration limits (profile ``[acceleration_limits]``): derivation, data and wiring."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.sim.sim_core import SimConfig, SimCore
from shared.robot.accel_limits import (
    RESERVE,
    joint_inertia_and_gravity,
    main,
    motor_accelerations,
    profile_table,
)
from shared.robot.mujoco_model import build_mujoco_robot
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import load_profile
from tests.support.profiles import g1_with_motor_acceleration_limits

#: A pose with the left arm forward and its forearm turned, so the wrist yaw axis is not vertical
#: and gravity loads it.
POSE = {
    "left_shoulder_pitch_joint": -1.2,
    "left_shoulder_roll_joint": 0.6,
    "left_elbow_joint": 0.3,
    "left_wrist_roll_joint": 1.0,
    "left_wrist_pitch_joint": 0.5,
}
JOINT = "left_wrist_yaw_joint"


def test_wrist_yaw_limit_against_a_hand_check_from_the_urdf():
    """M_jj of the last wrist joint by the parallel-axis theorem on the URDF inertia (Pinocchio merges
    the fixed hand into it) plus the armature, and its gravity torque as r x m g about the joint axis:
    MuJoCo's mass matrix and bias agree, and the profile's limit is within what the motor gives there."""
    prof = load_profile()
    full = pin.buildModelFromUrdf(str(prof.urdf_path))
    jid = full.getJointId(JOINT)
    body = full.inertias[jid]  # in the joint frame: mass, COM c, rotational inertia about the COM
    axis = np.array([0.0, 0.0, 1.0])  # a revolute joint about its local z (JointModelRZ)
    assert full.joints[jid].shortname() == "JointModelRZ"
    c = body.lever
    about_joint = body.inertia + body.mass * (c @ c * np.eye(3) - np.outer(c, c))
    armature = prof.actuators["armature"]
    m_jj_hand = armature + axis @ about_joint @ axis

    q = pin.neutral(full)
    for name, val in {**prof.rest, **POSE}.items():
        q[full.joints[full.getJointId(name)].idx_q] = val
    data = full.createData()
    pin.forwardKinematics(full, data, q)
    placement = data.oMi[jid]  # base (pelvis) fixed: world == base
    com = placement.act(c)
    weight = body.mass * np.array([0.0, 0.0, -9.81])
    gravity_hand = float((placement.rotation @ axis) @ np.cross(com - placement.translation, weight))
    assert abs(gravity_hand) > 0.05  # the pose loads the joint: gravity is part of the check

    robot = build_mujoco_robot(prof, gravity_compensation=False)
    m, d = robot.model, robot.data
    for name, val in POSE.items():
        d.qpos[m.joint(name).qposadr[0]] = val
    dof = np.array([m.joint(JOINT).dofadr[0]])
    inertia, bias = joint_inertia_and_gravity(m, d, dof)
    assert inertia[0] == pytest.approx(m_jj_hand, rel=1e-3)
    assert abs(bias[0]) == pytest.approx(abs(gravity_hand), rel=1e-3, abs=1e-4)

    effort = float(full.effortLimit[full.joints[jid].idx_v])
    assert effort == 5.0  # the URDF's wrist pitch/yaw motor
    at_pose = (effort - abs(gravity_hand)) / m_jj_hand
    limit = prof.joint_accelerations[JOINT]
    # The derivation keeps half the motor's worst case; this pose is one of the postures it covers.
    assert (1 - RESERVE) * at_pose * 0.9 < limit <= (1 - RESERVE) * at_pose


def test_profile_table_is_what_the_derivation_prints(capsys):
    """The G1 profile's [acceleration_limits] are the derivation's output, not hand-edited or stale
    (a changed URDF, armature or rest pose makes this fail until the table is recomputed)."""
    acc = motor_accelerations()
    prof = load_profile()
    printed = dict(
        line.split("  #")[0].split(" = ") for line in profile_table(acc).splitlines()[1:]
    )  # joint -> value text
    assert {k: float(v) for k, v in printed.items()} == prof.joint_accelerations
    # The motors cannot give the global cap: every limit is below it, the waist and shoulders far below.
    assert max(prof.joint_accelerations.values()) < prof.max_joint_acceleration
    assert np.all(acc.limit[: len(prof.waist)] < 50.0)
    assert main(["--samples", "50"]) == 0
    assert capsys.readouterr().out.startswith("[acceleration_limits]\nwaist_yaw_joint = ")


def test_model_amax_takes_the_per_joint_limits_capped_by_the_global_one(tmp_path):
    shipped = build_robot_model()  # the switch is off: the table is data only
    assert not shipped.profile.motor_acceleration_limits
    np.testing.assert_array_equal(shipped.amax, shipped.profile.max_joint_acceleration)
    rm = build_robot_model(g1_with_motor_acceleration_limits(tmp_path))
    prof = rm.profile
    expected = [min(prof.joint_accelerations[j], prof.max_joint_acceleration) for j in rm.joint_names]
    np.testing.assert_array_equal(rm.amax, expected)
    # The sim's servo target takes the same per-joint limits (in its own joint order).
    sim = SimCore(prof, SimConfig(watchdog=1.0))
    np.testing.assert_array_equal(sim.amax, [expected[rm.joint_names.index(j)] for j in sim.joint_names])
    # A global cap below a joint's entry wins for that joint.
    text = prof.source.read_text().replace("max_joint_acceleration = 1000.0", "max_joint_acceleration = 100.0")
    path = tmp_path / "capped.toml"
    path.write_text(text)
    capped = build_robot_model(str(path))
    np.testing.assert_array_equal(capped.amax, np.minimum(expected, 100.0))
    assert capped.amax[capped.joint_names.index("left_wrist_roll_joint")] == 100.0
    assert capped.amax[capped.joint_names.index("waist_pitch_joint")] == prof.joint_accelerations["waist_pitch_joint"]
