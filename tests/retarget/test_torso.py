"""The operator's chest rotation as the robot's waist angles (``services/retarget/torso.py``), published by the
retargeter (``TaskTargets.waist``), and the eval's ``waist_vs_operator_deg`` built on it."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import make_frame

from services.evaluation.metrics import published_waist, waist_vs_operator
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.retarget.torso import WaistMap, chest_rotation
from shared.messages import Bone
from shared.rotations import matrix_to_quat
from tests.evaluation.test_metrics import synthetic_trace

X, Y, Z = np.eye(3)


def rot(axis: np.ndarray, angle: float) -> np.ndarray:
    return pin.exp3(np.asarray(axis, dtype=float) * angle)


@pytest.fixture(scope="module")
def waist(robot17):
    return WaistMap(robot17)


@pytest.fixture(scope="module")
def chest_rest():
    """A rest chest orientation that is not the identity (a rig's own bone axes, a slight lean)."""
    return rot(np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), 0.7)


def test_the_g1_waist_axes_are_yaw_roll_pitch(waist):
    assert waist.joints == ("waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint")
    np.testing.assert_allclose(waist.axes, np.array([Z, X, Y]), atol=1e-12)


def test_the_rest_pose_maps_to_the_waist_rest(waist, chest_rest):
    np.testing.assert_allclose(waist(chest_rest, chest_rest), waist.rest, atol=1e-12)
    np.testing.assert_allclose(waist.rest, 0.0)


@pytest.mark.parametrize("joint, axis", [(0, Z), (1, X), (2, Y)])
@pytest.mark.parametrize("angle", [-0.4, 0.25])
def test_a_pure_chest_rotation_maps_to_that_joint_alone(waist, chest_rest, joint, axis, angle):
    """The chest turned about the pelvis's z (x, y) since the rest: only the yaw (roll, pitch) joint moves, by that
    angle; the rig's own chest axes (the rest orientation) do not matter."""
    q = waist(rot(axis, angle) @ chest_rest, chest_rest)
    want = np.zeros(3)
    want[joint] = angle
    np.testing.assert_allclose(q, want, atol=1e-12)


def test_a_rotation_past_a_range_clips_to_it(waist, chest_rest):
    """Roll 0.8 rad and pitch -0.9 rad are past the G1's +-0.52 rad (less the 0.02 rad margin); yaw 1 rad is not."""
    D = rot(Z, 1.0) @ rot(X, 0.8) @ rot(Y, -0.9)
    np.testing.assert_allclose(waist.angles(D @ chest_rest, chest_rest), [1.0, 0.8, -0.9], atol=1e-12)
    np.testing.assert_allclose(waist(D @ chest_rest, chest_rest), [1.0, 0.5, -0.5], atol=1e-12)
    assert waist.upper[1] == pytest.approx(0.5) and waist.lower[2] == pytest.approx(-0.5)


def test_the_split_turns_the_torso_link_as_the_chest_turned(waist, robot17):
    """Any chest rotation within the ranges: the torso link, posed at the waist angles by the robot's own forward
    kinematics, has turned by exactly that rotation since the rest."""
    rng = np.random.default_rng(3)
    R0 = robot17.frame_poses(robot17.q_rest, names=("torso_link",))["torso_link"][1]
    for _ in range(20):
        D = rot(Z, rng.uniform(-2, 2)) @ rot(X, rng.uniform(-0.5, 0.5)) @ rot(Y, rng.uniform(-0.5, 0.5))
        q = waist(D, np.eye(3))
        full = robot17.q_rest.copy()
        full[[robot17.joint_names.index(j) for j in waist.joints]] = q
        R = robot17.frame_poses(full, names=("torso_link",))["torso_link"][1]
        np.testing.assert_allclose(R @ R0.T, D, atol=1e-9)
        np.testing.assert_allclose(waist.rotation(q), D, atol=1e-9)


def _with_chest(frame, R=None, valid=True):
    if R is not None:
        frame.bones["chest"] = Bone(np.array([0.0, 0.0, 0.3]), matrix_to_quat(R), valid)
    return frame


def test_chest_rotation_needs_a_measured_valid_chest(chest_rest):
    assert chest_rotation(_with_chest(make_frame(0, 0.0))) is None  # no chest bone
    assert chest_rotation(_with_chest(make_frame(0, 0.0), chest_rest, valid=False)) is None
    marker = _with_chest(make_frame(0, 0.0), chest_rest)
    marker.oriented = False  # a marker-only source: the quaternion is a placeholder
    assert chest_rotation(marker) is None
    np.testing.assert_allclose(chest_rotation(_with_chest(make_frame(0, 0.0), chest_rest)), chest_rest, atol=1e-12)


def test_published_waist_is_against_the_first_measured_chest(robot14, workspace, chest_rest):
    """What the eval scores against: the waist angles the retargeter published, per frame seq. A clip whose first
    frame has no chest, then the rest, a 0.3 rad yaw and a pitch past the range: the rest is the first measured
    chest, the frame without one is NaN; a clip without any measured chest gives None."""
    frames = [
        make_frame(0, 0.0),
        _with_chest(make_frame(1, 0.01), chest_rest),
        _with_chest(make_frame(2, 0.02), rot(Z, 0.3) @ chest_rest),
        _with_chest(make_frame(3, 0.03), rot(Y, 0.7) @ chest_rest),
    ]
    rt = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    W = published_waist([rt.step(f) for f in frames])
    assert W.shape == (4, 3) and np.isnan(W[0]).all()
    np.testing.assert_allclose(W[1:], [[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 0.5]], atol=1e-12)
    rt = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    assert published_waist([rt.step(make_frame(0, 0.0)), rt.step(make_frame(1, 0.01))]) is None


def test_waist_vs_operator_is_the_largest_joint_gap_of_the_tracked_frame(robot17):
    """A trace whose waist holds yaw 0.2 rad against an operator at rest, then at yaw 0.2 with a roll of 0.1: the
    gap is 0.2 rad (11.46 deg), then 0.1 rad; ticks of a frame without a measured chest are left out."""
    tr = synthetic_trace(robot17, {})  # seq = tick // 16
    yaw = robot17.joint_names.index("waist_yaw_joint")
    tr.q[:, yaw] = 0.2
    frames = int(tr.seq.max()) + 1
    op = np.zeros((frames, 3))
    half = frames // 2
    op[half:] = [0.2, 0.1, 0.0]
    op[0] = np.nan  # the first frame measured no chest
    m = waist_vs_operator(tr, robot17, op)["waist_vs_operator_deg"]
    before, after = np.sum((tr.seq >= 1) & (tr.seq < half)), np.sum(tr.seq >= half)
    assert m["max"] == pytest.approx(np.degrees(0.2))
    assert m["mean"] == pytest.approx(np.degrees(0.2 * before + 0.1 * after) / (before + after))


def test_the_retargeter_publishes_the_operator_waist_against_the_calibration_frame(robot14, workspace, chest_rest):
    """The calibration (first) frame's chest is the rest; a later chest yawed 0.3 rad publishes waist (0.3, 0, 0);
    a frame without a chest publishes none; a pitch past the range is clipped and counted; the waist leaves the
    hand targets alone."""
    rt = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    first = rt.step(_with_chest(make_frame(0, 0.0), chest_rest))
    np.testing.assert_allclose(first.waist, 0.0, atol=1e-12)
    turned = rt.step(_with_chest(make_frame(1, 0.01), rot(Z, 0.3) @ chest_rest))
    np.testing.assert_allclose(turned.waist, [0.3, 0.0, 0.0], atol=1e-12)
    assert len(rt.step(make_frame(2, 0.02)).waist) == 0
    past = rt.step(_with_chest(make_frame(3, 0.03), rot(Y, 0.7) @ chest_rest))
    np.testing.assert_allclose(past.waist, [0.0, 0.0, 0.5], atol=1e-12)
    assert rt.counts["waist_clipped_waist_pitch_joint"] == 1
    assert (turned.targets["left_wrist"].p == rt.step(make_frame(4, 0.04)).targets["left_wrist"].p).all()


def test_a_new_calibration_takes_a_new_chest_rest(robot14, workspace, chest_rest):
    rt = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    rt.step(_with_chest(make_frame(0, 0.0), chest_rest))
    rt.request_recalibration()
    turned = rot(Z, 0.3) @ chest_rest
    np.testing.assert_allclose(rt.step(_with_chest(make_frame(1, 0.01), turned)).waist, 0.0, atol=1e-12)
