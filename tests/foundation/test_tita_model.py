"""The TITA-PiPER model against seed 002's Tables 1-2 and section 3, and MuJoCo == Pinocchio on it."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from shared.paths import MODELS_DIR
from shared.robot.description import DescriptionError, load_description, mjcf_path, to_mjcf
from shared.robot.wheeled import build_wheeled_robot, load_wheeled_profile

PROFILE = MODELS_DIR / "tita_piper.toml"

# Seed 002 Table 2: joint ranges [rad] and motor torques [N m].
TABLE2_RANGES = {
    "left_hip_out": (-0.78, 0.78),
    "left_hip_pitch": (-3.1, 1.6),
    "left_knee": (-2.7, -0.69),
    "j1": (-2.69, 2.69),
    "j2": (0.0, 3.40),
    "j3": (-3.05, 0.0),
    "j4": (-1.75, 1.95),
    "j5": (-1.31, 1.31),
    "j6": (-1.75, 1.75),
}
TABLE2_TORQUES = {"left_hip_out": 120.0, "left_hip_pitch": 120.0, "left_knee": 120.0, "left_wheel": 48.0}


@pytest.fixture(scope="module")
def robot():
    return build_wheeled_robot(PROFILE)


def test_generated_mjcf_is_in_sync_with_the_profile():
    desc = load_description(PROFILE)
    assert mjcf_path(PROFILE).read_text() == to_mjcf(desc)


def test_masses_match_table_1(robot):
    m = robot.mj_model
    mass = {m.body(i).name: float(m.body_mass[i]) for i in range(1, m.nbody)}
    assert mass["torso"] == pytest.approx(13.2)
    for side in ("left", "right"):
        assert mass[f"{side}_thigh"] == pytest.approx(3.1)
        assert mass[f"{side}_crus"] == pytest.approx(0.6)
        assert mass[f"{side}_wheel"] == pytest.approx(1.5)
    assert mass["upper_arm"] == pytest.approx(0.2)
    assert mass["forearm"] == pytest.approx(0.5)
    assert mass["gripper"] + mass["finger_left"] + mass["finger_right"] == pytest.approx(0.5)
    arm = ("arm_base", "link1", "upper_arm", "forearm", "link4", "link5", "gripper", "finger_left", "finger_right")
    assert sum(mass[b] for b in arm) == pytest.approx(4.2)  # PiPER's total weight (section 2)
    # Pinocchio reads the same masses from the same file.
    assert sum(i.mass for i in robot.pin_model.inertias) == pytest.approx(float(m.body_subtreemass[1]))


def test_lengths_match_table_1(robot):
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    mujoco.mj_kinematics(m, d)

    def dist(a, b):
        return float(np.linalg.norm(d.xpos[m.body(a).id] - d.xpos[m.body(b).id]))

    assert dist("left_thigh", "left_crus") == pytest.approx(0.200)  # hip pitch -> knee
    assert dist("left_crus", "left_wheel") == pytest.approx(math.hypot(0.200, 0.04))  # knee -> axle (40 mm out)
    assert m.geom_size[m.geom("left_wheel_geom").id][0] == pytest.approx(0.0927)
    assert dist("link1", "upper_arm") == pytest.approx(0.080)  # arm base height: J1 -> J2
    assert dist("upper_arm", "forearm") == pytest.approx(0.285)
    assert dist("forearm", "link4") == pytest.approx(0.215)
    torso = m.geom("torso_geom").id
    assert 2 * m.geom_size[torso][:2] == pytest.approx([0.50, 0.31])


def test_ranges_and_motors_match_table_2(robot):
    m = robot.mj_model
    for name, rng in TABLE2_RANGES.items():
        for side_name in {name, name.replace("left_", "right_")}:
            j = m.joint(side_name).id
            assert m.jnt_limited[j]
            assert tuple(m.jnt_range[j]) == pytest.approx(rng)
            pj = robot.pin_model.getJointId(side_name)
            iq = robot.pin_model.joints[pj].idx_q
            assert robot.pin_model.lowerPositionLimit[iq] == pytest.approx(rng[0])
            assert robot.pin_model.upperPositionLimit[iq] == pytest.approx(rng[1])
    assert not m.jnt_limited[m.joint("left_wheel").id]  # wheels turn freely
    for name, tau in TABLE2_TORQUES.items():
        assert tuple(m.actuator_ctrlrange[m.actuator(name).id]) == pytest.approx((-tau, tau))


def test_seed_frames_and_arm_axes(robot):
    """Σb at the torso centre; J1 yaw, J2/J3 pitch (section 3); Σa x out of the gripper, z its up."""
    prof = robot.profile
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    mujoco.mj_kinematics(m, d)
    sb = m.site(prof.torso_site).id
    assert d.site_xpos[sb] == pytest.approx(d.xpos[m.body("torso").id])
    assert d.site_xpos[sb] == pytest.approx(d.geom_xpos[m.geom("torso_geom").id])
    assert m.jnt_axis[m.joint("j1").id] == pytest.approx([0, 0, 1])
    assert m.jnt_axis[m.joint("j2").id] == pytest.approx([0, 1, 0])
    assert m.jnt_axis[m.joint("j3").id] == pytest.approx([0, 1, 0])
    # Arm stretched forward (J2 = π/2): Σa's x points forward (+x of Σb) and its z up.
    d.qpos[m.jnt_qposadr[m.joint("j2").id]] = math.pi / 2
    mujoco.mj_kinematics(m, d)
    Ra = d.site_xmat[m.site(prof.hand_site).id].reshape(3, 3)
    assert Ra[:, 0] == pytest.approx([1, 0, 0], abs=1e-12)
    assert Ra[:, 2] == pytest.approx([0, 0, 1], abs=1e-12)


def test_mujoco_and_pinocchio_agree_on_every_body(robot):
    """One description, two libraries: every body pose over random configurations (free base included)."""
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    model = robot.pin_model
    data = model.createData()
    rng = np.random.default_rng(9)
    names = [m.body(i).name for i in range(1, m.nbody)]
    for _ in range(30):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        d.qpos[:3] = rng.uniform(-1, 1, 3)
        d.qpos[3:7] = quat
        qp = pin.neutral(model)
        qp[:3], qp[3:7] = d.qpos[:3], np.r_[quat[1:], quat[0]]
        for j in range(1, m.njnt):
            lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-3.0, 3.0)
            v = rng.uniform(lo, hi)
            d.qpos[m.jnt_qposadr[j]] = v
            qp[model.joints[model.getJointId(m.joint(j).name)].idx_q] = v
        mujoco.mj_kinematics(m, d)
        pin.framesForwardKinematics(model, data, qp)
        for n in names:
            oMf = data.oMf[model.getFrameId(n, pin.BODY)]
            assert np.abs(oMf.translation - d.xpos[m.body(n).id]).max() < 1e-10
            assert np.abs(oMf.rotation - d.xmat[m.body(n).id].reshape(3, 3)).max() < 1e-10


def test_wheels_stand_on_the_floor_at_the_start_pose(robot):
    from services.wbc.runner import place_robot

    prof = robot.profile
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    place_robot(robot, d, prof.start_base, prof.start_arm)
    r = m.geom_size[m.geom("left_wheel_geom").id][0]
    for w in prof.wheels:
        assert d.xpos[m.body(w).id][2] == pytest.approx(r, abs=1e-9)
    assert d.qpos[2] == pytest.approx(prof.start_base[2])


def test_bad_description_is_refused_with_a_clear_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[[body]]\nname = "a"\nparent = "nowhere"\nmass = 1.0\nshape = { type = "box", size = [1, 1, 1] }\n')
    with pytest.raises(DescriptionError, match="parent 'nowhere'"):
        load_description(bad)
    bad.write_text('[[body]]\nname = "a"\nparent = "world"\nmass = 0.0\nshape = { type = "box", size = [1, 1, 1] }\n')
    with pytest.raises(DescriptionError, match="mass must be > 0"):
        load_description(bad)


def test_profile_loads_planner_settings():
    prof = load_wheeled_profile("tita_piper")
    assert prof.arm == ("j1", "j2", "j3")
    assert prof.z_range[0] >= 0.30 and prof.z_range[1] <= 0.4927  # Table 1's H 300-490 mm
