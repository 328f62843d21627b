"""Swivel elbow placement and the forearm-relative orientation map (services/retarget/elbow.py, orientation.py)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.retarget.elbow import ArmGeometry, human_swivel
from services.retarget.orientation import ForearmOrientationMap, arm_alignment, calibration_posture


@pytest.fixture(scope="module")
def left(robot14):
    return ArmGeometry.measure(robot14, "left")


def test_placed_elbow_has_the_robot_arm_lengths(left):
    rng = np.random.default_rng(1)
    for _ in range(50):
        d = rng.uniform(left.reach[0], left.reach[1])
        u = rng.normal(size=3)
        wrist = left.centre + d * u / np.linalg.norm(u)
        e = left.place(wrist, rng.normal(size=3))
        assert np.linalg.norm(e - left.centre) == pytest.approx(left.upper, abs=1e-9)
        assert np.linalg.norm(wrist - e) == pytest.approx(left.fore, abs=1e-9)


def test_placed_elbow_points_where_the_operator_elbow_points(left):
    wrist = left.centre + np.array([0.15, 0.0, -0.2])
    for side in (np.array([0.0, 1.0, 0.0]), np.array([0.0, -1.0, 0.0])):
        e = left.place(wrist, side)
        axis = (wrist - left.centre) / np.linalg.norm(wrist - left.centre)
        off = (e - left.centre) - ((e - left.centre) @ axis) * axis
        assert off @ side > 0.05  # on the operator's side of the shoulder-wrist line


def test_robot_pose_is_recovered_from_its_own_wrist_and_swivel(robot14, left):
    """A robot configuration with neutral wrist: its wrist plus its own swivel give back its elbow
    (up to the G1's non-intersecting shoulder axes: about 1 cm median over random poses)."""
    rng = np.random.default_rng(3)
    wrist_joints = robot14.indices(robot14.profile.arms["left"].wrist)
    errs = []
    for q in robot14.random_configurations(100, rng):
        q[wrist_joints] = 0.0
        P = robot14.frame_poses(q, names=("left_elbow", "left_wrist"))
        sw = human_swivel(left.centre, P["left_elbow"][0], P["left_wrist"][0])
        errs.append(np.linalg.norm(left.place(P["left_wrist"][0], sw) - P["left_elbow"][0]))
    assert np.median(errs) < 0.015 and max(errs) < 0.06


def test_reach_clamp_moves_only_out_of_reach_wrists(left):
    inside = left.centre + np.array([0.0, 0.0, -0.25])
    np.testing.assert_allclose(left.reachable(inside), inside)
    near = left.centre + np.array([0.0, 0.0, -0.05])
    assert np.linalg.norm(left.reachable(near) - left.centre) == pytest.approx(left.reach[0])
    far = left.centre + np.array([0.0, 0.0, -0.6])
    assert np.linalg.norm(left.reachable(far) - left.centre) == pytest.approx(left.reach[1])


def test_calibration_posture_reaches_a_consistent_pair(robot14, left):
    wrist = left.centre + np.array([0.1, 0.05, -0.25])
    elbow = left.place(wrist, np.array([-1.0, 0.3, 0.0]))
    q = calibration_posture(robot14, "left", wrist, elbow)
    P = robot14.frame_poses(q, names=("left_elbow", "left_wrist"))
    assert np.linalg.norm(P["left_wrist"][0] - wrist) < 0.01
    assert np.linalg.norm(P["left_elbow"][0] - elbow) < 0.015
    wrist_joints = robot14.indices(robot14.profile.arms["left"].wrist)
    assert len(wrist_joints) == 3 and np.all(q[wrist_joints] == 0.0)


def test_forearm_map_gives_calibration_orientation_and_follows_the_forearm():
    rng = np.random.default_rng(4)
    R_H0, R_U0 = pin.exp3(rng.normal(size=3)), pin.exp3(rng.normal(size=3))
    up_H, fore_H = np.array([0.0, 0.02, -0.28]), np.array([0.1, 0.0, -0.2])
    up_U, fore_U = np.array([0.02, 0.0, -0.19]), np.array([0.15, 0.02, -0.1])
    m = ForearmOrientationMap(R_H0, R_U0, arm_alignment(up_H, fore_H, up_U, fore_U))
    np.testing.assert_allclose(m.with_alignment(R_H0, arm_alignment(up_H, fore_H, up_U, fore_U)), R_U0, atol=1e-12)
    # The whole operator arm turns by G (hand rigid with the forearm) and the robot arm by G2:
    # the robot hand turns by G2 with its forearm (wrist joints unchanged).
    G, G2 = pin.exp3(np.array([0.3, -0.2, 0.5])), pin.exp3(np.array([-0.1, 0.4, 0.2]))
    A = arm_alignment(G @ up_H, G @ fore_H, G2 @ up_U, G2 @ fore_U)
    np.testing.assert_allclose(m.with_alignment(G @ R_H0, A), G2 @ R_U0, atol=1e-9)


def test_forearm_blend_makes_the_alignment_continuous_as_the_arm_straightens():
    """The operator's arm straightens in the y-z plane (normal x) while the robot's stays bent in the x-z plane
    (normal y): the frames' alignment carries a 90 deg turn about the forearm that the straight-arm fallback
    does not. Switching at STRAIGHT_SIN jumps by it in one step; blended, the alignment moves by a few degrees
    per 0.002 rad step, and is the unblended one while both arms are well bent."""
    up_H, up_U = np.array([0.0, 0.0, -0.28]), np.array([0.0, 0.0, -0.19])
    fore_U = 0.2 * np.array([np.sin(0.6), 0.0, -np.cos(0.6)])
    steps = {}
    for blend in (False, True):
        prev, worst = None, 0.0
        for theta in np.arange(0.5, 0.0, -0.002):
            A = arm_alignment(up_H, 0.25 * np.array([0.0, np.sin(theta), -np.cos(theta)]), up_U, fore_U, blend)
            if prev is not None:
                worst = max(worst, float(np.degrees(np.linalg.norm(pin.log3(prev.T @ A)))))
            prev = A
        steps[blend] = worst
    assert steps[False] > 45.0
    assert steps[True] < 4.0
    fore_H = 0.25 * np.array([0.0, np.sin(0.5), -np.cos(0.5)])
    np.testing.assert_allclose(
        arm_alignment(up_H, fore_H, up_U, fore_U, True), arm_alignment(up_H, fore_H, up_U, fore_U)
    )


def test_an_elbow_whose_wrist_marker_drops_out_is_held_with_it(robot14, workspace):
    """A source that loses a wrist marker for a few frames: the swivel elbow cannot be placed, and the elbow target
    is held (invalid, at rest) where it was with its wrist, not moved to the box map's elbow (on the Vicon box lift
    the two placements were 7.5 cm apart, and the target flipped between them). A source without wrists at all
    keeps the box-mapped elbow."""
    from services.retarget.retargeter import RetargetConfig, Retargeter
    from tests.retarget.conftest import make_frame

    rt = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    lift = {"left_wrist": np.array([0.25, 0.0, 0.25]), "left_elbow": np.array([0.05, 0.05, 0.0])}
    out = [rt.step(make_frame(k + 1, 0.01 * k, offsets=lift, invalid=("left_wrist",) if 5 <= k < 8 else ()))
           for k in range(10)]  # fmt: skip
    before = out[4].targets["left_elbow"]
    for k in (5, 6, 7):
        el = out[k].targets["left_elbow"]
        assert not el.valid and not out[k].targets["left_wrist"].valid
        np.testing.assert_allclose(el.p, before.p, atol=1e-12)
        assert not el.v.any()
    assert out[8].targets["left_elbow"].valid and out[5].targets["right_elbow"].valid  # back; the other arm untouched
    np.testing.assert_allclose(out[8].targets["left_elbow"].p, before.p, atol=1e-6)  # the same pose again
    mapped = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    for k in range(3):
        frame = make_frame(k + 1, 0.01 * k, offsets=lift, drop=("left_wrist",) if k == 2 else ())
        el = mapped.step(frame).targets["left_elbow"]
    assert el.valid and np.linalg.norm(el.p - before.p) > 0.01  # no wrist bone: the box map's elbow, elsewhere


def test_a_straight_operator_arm_keeps_the_elbow_target_still(robot14, workspace):
    """The operator's arm hangs straight (the elbow within millimetres of the shoulder-wrist line, marker noise), while
    the robot's wrist target is short of full stretch, so its elbow is bent and needs a swivel direction. From the
    operator's noise alone that direction turns every frame; with the previous placement as prior it stays put."""
    from services.retarget.elbow import human_swivel
    from services.retarget.retargeter import RetargetConfig, Retargeter
    from tests.retarget.conftest import REST_LEFT, make_frame

    rt = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    arm = rt.arms["left"]
    rng = np.random.default_rng(7)
    sh, wr = (np.array(REST_LEFT[f"left_{b}"]) for b in ("shoulder", "wrist"))
    straight = sh + 0.53 * (wr - sh) - np.array(REST_LEFT["left_elbow"])  # the elbow on the shoulder-wrist line
    elbows, plain = [], []
    for k in range(60):
        noise = {"left_elbow": straight + rng.normal(scale=0.002, size=3)}
        frame = make_frame(k + 1, k / 30, offsets=noise)
        tg = rt.step(frame).targets
        bones = [frame.bones[f"left_{b}"].p for b in ("shoulder", "elbow", "wrist")]
        assert np.linalg.norm(human_swivel(*bones)) < 0.01
        elbows.append(tg["left_elbow"].p)
        plain.append(arm.place(tg["left_wrist"].p, human_swivel(*bones)))  # no prior: the noise's direction
    moved = [np.linalg.norm(np.diff(np.array(e[10:]), axis=0), axis=1).max() for e in (elbows, plain)]
    assert np.linalg.norm(elbows[-1] - arm.centre) == pytest.approx(arm.upper, abs=1e-6)  # still on the robot's arm
    assert moved[1] > 0.04 and moved[0] < 0.5 * moved[1], moved  # measured 5.5 and 2.1 cm
