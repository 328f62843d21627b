"""Robot profile schema: joint roles, acceleration limits, and refusal of bad profiles."""

from __future__ import annotations

import re

import numpy as np
import pytest

from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import ProfileError, load_profile
from shared.targets import SIDES


def _variant(tmp_path, name: str, edit) -> str:
    """Write a copy of the default profile after ``edit(text) -> text``; returns its path."""
    text = load_profile().source.read_text()
    path = tmp_path / f"{name}.toml"
    path.write_text(edit(text.replace(f'name = "{load_profile().name}"', f'name = "{name}"')))
    return str(path)


def test_g1_profile_roles():
    prof = load_profile()
    for side in SIDES:
        arm = prof.arms[side]
        # the roles split the chain exactly: shoulder + elbow + wrist, in order
        assert (*arm.shoulder, arm.elbow, *arm.wrist) == arm.joints
        assert len(arm.shoulder) == 3 and len(arm.wrist) == 3
    assert prof.controlled_joints()[: len(prof.waist)] == prof.waist
    assert prof.max_joint_acceleration > 0 and set(prof.arms_out) <= set(prof.controlled_joints())


def test_velocity_limits_table_lowers_its_joints_only(tmp_path):
    """A [velocity_limits] entry caps its joint below [model] max_joint_velocity; the other joints keep the cap, and
    an entry above the cap changes nothing (each joint: the smallest of entry, cap and URDF limit)."""
    rm = build_robot_model()
    prof = rm.profile
    assert prof.joint_velocities, "the G1 profile has a [velocity_limits] table"
    for j, v in zip(rm.joint_names, rm.vmax):
        want = min(prof.joint_velocities.get(j, np.inf), prof.max_joint_velocity)
        assert v == pytest.approx(want), (j, v, want)
    assert rm.vmax[0] < prof.max_joint_velocity  # the waist, listed in the table
    fast_elbow = _variant(
        tmp_path,
        "fast_elbow",
        lambda t: t.replace("[velocity_limits]\n", "[velocity_limits]\nleft_elbow_joint = 100.0\n"),
    )
    slow_elbow = _variant(
        tmp_path,
        "slow_elbow",
        lambda t: t.replace("[velocity_limits]\n", "[velocity_limits]\nleft_elbow_joint = 0.5\n"),
    )
    e = rm.joint_names.index("left_elbow_joint")
    assert build_robot_model(fast_elbow).vmax[e] == prof.max_joint_velocity
    slow = build_robot_model(slow_elbow)
    assert slow.vmax[e] == 0.5 and np.array_equal(np.delete(slow.vmax, e), np.delete(rm.vmax, e))


def test_amax_beside_vmax():
    rm = build_robot_model()
    assert rm.amax.shape == rm.vmax.shape == (rm.nq,)
    assert np.all(rm.amax == [rm.profile.joint_acceleration(j) for j in rm.joint_names])
    assert np.all(rm.amax <= rm.profile.max_joint_acceleration)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda t: re.sub(r"^max_joint_acceleration = .*$", "max_joint_acceleration = -1.0", t, flags=re.M),
            "max_joint_acceleration",
        ),
        (lambda t: re.sub(r"^max_joint_acceleration = .*$", "", t, flags=re.M), "max_joint_acceleration"),
        (lambda t: t.replace('elbow = "left_elbow_joint"', 'elbow = "left_knee_joint"'), r"\[arms.left\] elbow"),
        (lambda t: t.replace("[arms.right]", "[arms.righty]"), "missing field 'right'"),
        (lambda t: t.replace('left_elbow = "left_elbow_link"', ""), "lacks"),
        (
            lambda t: t.replace('waist = ["waist_yaw_joint",', 'waist = ["left_elbow_joint", "waist_yaw_joint",'),
            "twice",
        ),
        (lambda t: t.replace("max_joint_velocity = 8.0", 'max_joint_velocity = "fast"'), "max_joint_velocity"),
        (lambda t: t.replace("left_shoulder_pitch_joint = -0.3", "left_knee_joint = -0.3"), "arms_out"),
        (
            lambda t: re.sub(r"^waist_pitch_joint = .*$", "waist_pitch_joint = 0.0", t, flags=re.M),
            r"\[acceleration_limits\] waist_pitch_joint must be a positive number",
        ),
        (
            lambda t: re.sub(r"^waist_pitch_joint = .*$", 'waist_pitch_joint = "slow"', t, flags=re.M),
            r"\[acceleration_limits\] waist_pitch_joint must be a number",
        ),
        (
            lambda t: t.replace("motor_acceleration_limits = false", 'motor_acceleration_limits = "yes"'),
            r"\[model\] motor_acceleration_limits must be true or false",
        ),
        (
            lambda t: t.replace("motor_acceleration_limits = false", "motor_acceleration_limits = true").replace(
                "[acceleration_limits]", "[unused_acceleration_limits]"
            ),
            "motor_acceleration_limits = true needs an \\[acceleration_limits\\] table",
        ),
        (
            lambda t: t.replace("[acceleration_limits]\n", "[acceleration_limits]\nleft_kneee_joint = 10.0\n"),
            r"\[acceleration_limits\] names joints that are not in the URDF: \['left_kneee_joint'\]",
        ),
        (
            lambda t: t.replace("[velocity_limits]\n", "[velocity_limits]\nwaist_yawn_joint = 1.0\n"),
            r"\[velocity_limits\] names joints that are not in the URDF: \['waist_yawn_joint'\]",
        ),
        (
            lambda t: t.replace("[velocity_limits]\n", "[velocity_limits]\nleft_elbow_joint = -2.0\n"),
            r"\[velocity_limits\] left_elbow_joint must be a positive number",
        ),
        (
            lambda t: t.replace("[velocity_limits]\n", '[velocity_limits]\nleft_elbow_joint = "slow"\n'),
            r"\[velocity_limits\] left_elbow_joint must be a number",
        ),
        (
            lambda t: t.replace("braking_distance = 0.025", "braking_distance = 0.01"),
            r"\[collision\] needs safety_distance <= braking_distance < influence_distance and braking_deceleration "
            r">= 0, got 0.01, 0.0",
        ),
        (
            lambda t: t.replace("braking_deceleration = 0.0", "braking_deceleration = -1.0"),
            r"\[collision\] needs safety_distance <= braking_distance .* got 0.025, -1.0",
        ),
        (
            lambda t: t.replace("[orientation_frames]\n", '[orientation_frames]\nleft_hand = "left_wrist_yaw_link"\n'),
            r"\[orientation_frames\] names targets that are not in \[frames\]: \['left_hand'\]",
        ),
        (
            lambda t: t.replace("[orientation_frames]\n", '[orientation_frames]\nleft_elbow = "left_elbow_lnk"\n'),
            r"\[orientation_frames\] names links that are not in the URDF: \['left_elbow_lnk'\]",
        ),
    ],
)
def test_bad_profiles_are_refused_with_the_field(tmp_path, edit, message):
    path = _variant(tmp_path, "bad", edit)
    with pytest.raises(ProfileError, match=message) as err:
        load_profile(path)
    assert "\n" not in str(err.value)  # a one-line error
