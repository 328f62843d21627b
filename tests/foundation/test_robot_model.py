"""One robot description feeds Pinocchio and MuJoCo; robots are data files."""

from __future__ import annotations

import numpy as np
import pytest

from shared.robot.mujoco_model import build_mujoco_robot
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import DEFAULT_PROFILE, ProfileError, load_profile


@pytest.fixture(scope="module")
def models():
    rm = build_robot_model()
    return rm, build_mujoco_robot(joint_names=rm.joint_names)


def test_profile_has_arms_and_waist():
    prof = load_profile()
    assert len(prof.controlled_joints(True)) == 17 and len(prof.controlled_joints(False)) == 14
    assert prof.urdf_path.exists()


def test_pinocchio_and_mujoco_forward_kinematics_agree(models):
    rm, mj = models
    rng = np.random.default_rng(1)
    worst = 0.0
    for q in rm.random_configurations(120, rng):
        for name, (p, R) in rm.frame_poses(q).items():
            mj.set_q(q)
            p2, R2 = mj.frame_pose(name)
            worst = max(worst, float(np.abs(p - p2).max()), float(np.abs(R - R2).max()))
    assert worst < 1e-6


def test_limits_and_rest(models):
    rm, mj = models
    assert np.all(rm.lower < rm.upper)
    assert np.all((rm.q_rest >= rm.lower) & (rm.q_rest <= rm.upper))
    assert np.all(rm.vmax <= rm.profile.max_joint_velocity) and np.all(rm.vmax > 0)
    # MuJoCo model: pelvis welded (no free joint), a servo on every joint.
    assert mj.model.nu == mj.model.njnt and mj.model.nq == mj.model.njnt


def test_second_profile_is_a_file(tmp_path):
    src = load_profile().source.read_text()
    alt = src.replace(f'name = "{DEFAULT_PROFILE}"', 'name = "g1_arms_up"').replace(
        "left_elbow_joint = 1.2", "left_elbow_joint = 0.3"
    )
    path = tmp_path / "g1_arms_up.toml"
    path.write_text(alt)
    rm = build_robot_model(load_profile(path))
    i = rm.joint_names.index(rm.profile.arms["left"].elbow)
    assert rm.profile.name == "g1_arms_up" and rm.q_rest[i] == pytest.approx(0.3)


def test_unknown_profile_lists_known():
    with pytest.raises(ProfileError, match=DEFAULT_PROFILE):
        load_profile("no_such_robot")
