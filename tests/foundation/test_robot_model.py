"""One robot description feeds Pinocchio and MuJoCo; robots are data files."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from shared.kinematics.configuration import Configuration
from shared.robot.mujoco_model import build_mujoco_robot
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import DEFAULT_PROFILE, ProfileError, load_profile
from shared.targets import SIDES, wrist_of


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


def test_wrist_target_is_the_pitch_axis_and_turns_with_the_hand(models):
    """The G1's wrist target (``[frames]`` + ``[orientation_frames]``): its position is the wrist pitch axis, which
    no wrist joint moves, and its orientation the hand's, which each wrist joint turns; Configuration's pose and
    Jacobian rows are those of each frame, checked against finite differences."""
    rm, _ = models
    rng = np.random.default_rng(3)
    for q in rm.random_configurations(5, rng):
        conf = Configuration(rm, q)
        for side in SIDES:
            w = wrist_of(side)
            p, R = (x.copy() for x in conf.get_frame_pose(w))
            J = conf.get_frame_jacobian(w).copy()
            hand = rm.model.getFrameId(rm.profile.orientation_frame(w))
            assert np.allclose(R, rm.forward(q).oMf[hand].rotation)
            for j in rm.indices(rm.profile.arms[side].wrist):
                q2 = q.copy()
                q2[j] += 0.3
                p2, R2 = rm.frame_poses(q2, names=(w,))[w]
                assert np.linalg.norm(p2 - p) < 1e-9  # the wrist point stays
                assert np.linalg.norm(pin.log3(R2 @ R.T)) == pytest.approx(0.3)  # the hand turns
            dq = 1e-6 * rng.normal(size=rm.nq)
            p3, R3 = Configuration(rm, q + dq).get_frame_pose(w)
            np.testing.assert_allclose(J[:3] @ dq, p3 - p, atol=1e-10)
            np.testing.assert_allclose(J[3:] @ dq, pin.log3(R3 @ R.T), atol=1e-10)
