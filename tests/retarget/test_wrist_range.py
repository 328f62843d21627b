"""Wrist orientation targets within the wrist joints' ranges (``RetargetConfig.wrist_range``)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.evaluation.runner import clip_targets
from services.ingest import load_clip
from services.retarget.elbow import ArmGeometry
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.retarget.wrist_range import WristRange, euler_xyz, from_euler_xyz
from shared.rotations import quat_to_matrix

#: The implied elbow link is a model (the elbow link's offset from the arm plane varies with the posture):
#: on flexed arms it is within ~2 deg at the median, ~8 deg at p99 of random postures.
MODEL_DEG = 4.0


def _angle_deg(R1: np.ndarray, R2: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(pin.log3(R1.T @ R2))))


def _left(robot, wrist_angles) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Elbow and wrist positions (3,) [m], wrist and elbow link orientations (3, 3) of a bent left arm with
    the wrist joints at ``wrist_angles`` (3,) [rad] (forward kinematics ignores the joint limits)."""
    q = robot.q_rest.copy()
    q[:7] = [-0.5, 0.4, 0.1, 0.3, *wrist_angles]
    poses = robot.frame_poses(q, names=("left_elbow", "left_wrist"))
    return poses["left_elbow"][0], poses["left_wrist"][0], poses["left_wrist"][1], poses["left_elbow"][1]


@pytest.fixture(scope="module")
def left_range(robot14):
    return WristRange(robot14, "left", ArmGeometry.measure(robot14, "left").centre)


def test_euler_round_trip():
    e = np.array([0.7, -1.2, 1.4])
    assert np.allclose(euler_xyz(from_euler_xyz(e)), e)


def test_a_target_inside_the_ranges_is_unchanged(robot14, left_range):
    """Wrist joints well inside their ranges: the very target object is published back."""
    left_range.reset()
    elbow, wrist, R, _ = _left(robot14, (0.8, -0.6, 0.5))
    assert left_range(R, elbow, wrist) is R


def test_a_roll_past_its_range_maps_to_the_boundary(robot14, left_range):
    """The hand rolled 0.6 rad past the wrist roll stop (pitch and yaw inside): the published target is
    the boundary roll with the same pitch and yaw, measured against the true elbow link."""
    left_range.reset()
    lo, hi = left_range.lower, left_range.upper
    asked = np.array([hi[0] + 0.6, 0.3, -0.4])
    elbow, wrist, R, R_E = _left(robot14, asked)
    out = left_range(R, elbow, wrist)
    got = euler_xyz(R_E.T @ out)  # the wrist joint angles the true elbow link needs for it
    assert np.degrees(abs(got[0] - hi[0])) < MODEL_DEG
    assert np.degrees(np.abs(got[1:] - asked[1:])).max() < MODEL_DEG
    # it moved by about the excess, not more
    assert abs(_angle_deg(out, R) - np.degrees(0.6)) < MODEL_DEG
    # and within the ranges by the implied link (what the option guarantees)
    e = left_range.joint_angles(out, elbow, wrist)
    assert np.all(e >= lo - 1e-9) and np.all(e <= hi + 1e-9)


def test_continuous_across_the_boundary(robot14, left_range):
    """A yaw sweeping through its stop in 0.01 rad steps: the published target never steps more than the
    asked one (plus the model's wobble), and past the stop it stays put."""
    left_range.reset()
    hi = left_range.upper[2]
    prev_out, steps, past = None, [], []
    for yaw in np.arange(hi - 0.3, hi + 0.5, 0.01):
        elbow, wrist, R, _ = _left(robot14, (0.2, 0.1, yaw))
        out = left_range(R, elbow, wrist)
        if prev_out is not None:
            steps.append(_angle_deg(prev_out, out))
        if yaw > hi + 0.05:
            past.append(left_range.joint_angles(out, elbow, wrist)[2])
        prev_out = out
    assert max(steps) < np.degrees(0.01) * 1.5
    assert np.ptp(past) < 1e-6 and abs(past[0] - hi) < 1e-6


def test_the_retargeter_publishes_wrists_within_the_ranges_on_the_vicon_clip(robot14, c3d_dir):
    """The Vicon marker clip has no hand orientations (identity quaternions: the hand held fixed in the
    pelvis frame while the forearm moves), which asks the right wrist for up to ~60 deg past its stops.
    With the option every published right wrist target is within the ranges of the implied forearm;
    without it, many are not."""
    clip = load_clip(c3d_dir / "ezc3d-testFiles_Vicon.c3d")
    out = {}
    for on in (False, True):
        rt = Retargeter(RetargetConfig(wrist_range=on), robot=robot14)
        targets = clip_targets(clip, rt)
        check = WristRange(robot14, "right", rt.arms["right"].centre)
        past = []
        for tt in targets:
            w, e = tt.targets["right_wrist"], tt.targets["right_elbow"]
            if not (w.valid and e.valid):
                continue
            ang = check.joint_angles(quat_to_matrix(w.q), e.p, w.p)
            past.append(max(np.max(ang - check.upper), np.max(check.lower - ang), 0.0))
        out[on] = (np.degrees(np.array(past)), rt.counts["wrist_range_right"])
    off, on = out[False][0], out[True][0]
    assert np.mean(off > 5.0) > 0.3  # the unprojected targets are past the stops on many frames
    assert on.max() < 0.1  # (the implied link moves a little with the clipped hand)
    assert out[True][1] > 0 and out[False][1] == 0
