"""Consistent targets: the published wrist position, wrist orientation and elbow one arm posture meets."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import make_frame, targets_without_and_with

from services.evaluation.reachability import ArmIk as CheckIk
from services.evaluation.reachability import check_targets
from services.retarget.consistent import ConsistentArm
from services.retarget.elbow import ArmGeometry
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.rotations import quat_to_matrix
from shared.wrist_only import wrists_only

ARM = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow")


def _posture(robot, k: float) -> np.ndarray:
    """A left-arm posture (robot.nq,) [rad] well inside the limits, moving slowly with k."""
    q = robot.q_rest.copy()
    q[:7] = [-0.4 + 0.3 * np.sin(k), 0.35, 0.2 * np.cos(k), 0.9 + 0.2 * np.sin(0.7 * k), 0.3, -0.2, 0.25 * np.sin(k)]
    return q


def _triple(robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left wrist position (3,) [m], elbow position (3,) [m] and wrist orientation (3, 3) of posture q."""
    poses = robot.frame_poses(q, names=("left_wrist", "left_elbow"))
    return poses["left_wrist"][0], poses["left_elbow"][0], poses["left_wrist"][1]


def _angle_deg(R1: np.ndarray, R2: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(pin.log3(R1 @ R2.T))))


def test_an_unreachable_triple_is_published_reachable(robot14):
    """Elbow 3 cm beyond the upper arm's length and the hand turned 40 deg: no posture meets the triple;
    the published one is met (forward kinematics of the full model) within 1 mm and 1 deg."""
    arm = ConsistentArm(robot14, "left")
    wrist, elbow, R = _triple(robot14, _posture(robot14, 0.3))
    geo = ArmGeometry.measure(robot14, "left")
    out = elbow - geo.centre
    bad_elbow = elbow + 0.03 * out / np.linalg.norm(out)
    bad_R = pin.exp3(np.radians(40.0) * np.array([0.0, 0.6, 0.8])) @ R
    # the mapped pair alone is out of reach (independent IK of the evaluation)
    assert CheckIk(robot14, "left").solve(wrist, bad_elbow, tol=1e-4)[0] > 0.01
    new_elbow, new_R, _ = arm(wrist, bad_elbow, bad_R)
    q = arm.ik.full()
    assert np.all(q >= robot14.lower) and np.all(q <= robot14.upper)
    got_w, got_e, got_R = _triple(robot14, q)
    assert np.linalg.norm(got_w - wrist) < 1e-3
    assert np.linalg.norm(got_e - new_elbow) < 1e-3
    assert _angle_deg(got_R, new_R) < 1.0
    # and the pair passes the evaluation's independent IK check
    assert CheckIk(robot14, "left").solve(wrist, new_elbow, tol=1e-3)[0] <= 1e-3
    # the targets moved (it is not the input published back), the elbow by about its 3 cm
    assert 0.02 < np.linalg.norm(new_elbow - bad_elbow) < 0.04


def test_a_consistent_triple_is_published_unchanged_and_followed_continuously(robot14):
    """Targets from a slowly moving posture: published as given (first frame from rest too)."""
    arm = ConsistentArm(robot14, "left")
    worst_p, worst_deg, iters = 0.0, 0.0, []
    for k in np.linspace(0.0, 2.0, 60):
        wrist, elbow, R = _triple(robot14, _posture(robot14, k))
        arm.ik.iterations = 0
        new_elbow, new_R, _ = arm(wrist, elbow, R)
        iters.append(arm.ik.iterations)
        worst_p = max(worst_p, float(np.linalg.norm(new_elbow - elbow)))
        worst_deg = max(worst_deg, _angle_deg(new_R, R))
    assert worst_p < 5e-4 and worst_deg < 0.2
    # warm-started from the previous frame's posture: no more than the per-frame iterations after the first
    assert max(iters[1:]) <= arm.iters < iters[0]


def test_an_inconsistent_target_moving_slowly_gives_continuous_targets(robot14):
    """The 3 cm elbow offset along a slow motion: the published targets move as little as the input."""
    arm = ConsistentArm(robot14, "left")
    geo = ArmGeometry.measure(robot14, "left")
    prev, steps_in, steps_out, rot_out = None, [], [], []
    for k in np.linspace(0.0, 2.0, 80):
        wrist, elbow, R = _triple(robot14, _posture(robot14, k))
        out = elbow - geo.centre
        elbow = elbow + 0.03 * out / np.linalg.norm(out)
        new_elbow, new_R, _ = arm(wrist, elbow, R)
        if prev is not None:
            steps_in.append(np.linalg.norm(elbow - prev[0]))
            steps_out.append(np.linalg.norm(new_elbow - prev[1]))
            rot_out.append(_angle_deg(new_R, prev[2]))
        prev = (elbow, new_elbow, new_R)
    assert max(steps_out) < 2.0 * max(steps_in)
    assert max(rot_out) < 3.0  # the input turns about 1.5 deg a frame


def test_a_local_minimum_against_a_stop_is_left(robot14):
    """A warm start on the wrong branch (shoulder roll at its stop, wrist out of reach from there) is
    recovered: the wrist is met again."""
    arm = ConsistentArm(robot14, "left")
    q = robot14.q_rest.copy()
    q[:7] = [-1.8, 0.45, 0.0, -0.4, 0.0, -0.2, 0.0]  # arm raised forward (pitch)
    wrist, elbow, R = _triple(robot14, q)
    arm.ik.q = np.clip([0.2, 2.3, 1.6, -0.4, -0.25, -0.1, 0.2], arm.ik.lower, arm.ik.upper)  # raised by roll
    arm._fresh = False
    arm(wrist, elbow, R)
    assert np.linalg.norm(_triple(robot14, arm.ik.full())[0] - wrist) < 1e-3
    assert arm.recoveries == 1


def test_real_clip_pairs_become_reachable(bvh_clips, robot14, workspace):
    """guide_normal: a third of the mapped wrist + elbow pairs fail the evaluation's IK check; with
    consistent targets none do, and the wrist positions are the mapped ones."""
    out = targets_without_and_with(bvh_clips, "guide_normal", workspace, robot14, "consistent_targets")
    plain, pair = (check_targets(robot14, out[on]).fraction(pair=True) for on in (False, True))
    assert plain < 0.9 and pair == 1.0
    for a, b in zip(out[False], out[True], strict=True):
        for t in ("left_wrist", "right_wrist"):
            assert np.array_equal(a.targets[t].p, b.targets[t].p)


def test_wrist_only_frames_are_left_as_mapped_and_a_gap_restarts_from_rest(robot14, workspace):
    on = Retargeter(RetargetConfig(consistent_targets=True), workspace=workspace, robot=robot14)
    off = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    lift = {"left_wrist": np.array([0.15, 0.0, 0.25]), "left_elbow": np.array([0.05, 0.05, 0.1])}
    for r in (on, off):
        r.step(make_frame(1, 0.0))
    a, b = (r.step(make_frame(2, 1 / 30, offsets=lift)) for r in (on, off))
    assert np.linalg.norm(a.targets["left_elbow"].p - b.targets["left_elbow"].p) > 1e-3  # adjusted
    # wrist-only: nothing to make consistent, published as the plain retargeter does
    a, b = (r.step(wrists_only(make_frame(3, 2 / 30, offsets=lift))) for r in (on, off))
    for t in ("left_wrist", "right_wrist"):
        assert np.array_equal(a.targets[t].p, b.targets[t].p) and np.allclose(a.targets[t].q, b.targets[t].q)
    # after a gap the posture is solved from rest: as a fresh solver on the same mapped targets
    lift2 = {"left_wrist": np.array([0.25, 0.1, 0.3]), "left_elbow": np.array([0.1, 0.1, 0.1])}
    a, b = (r.step(make_frame(4, 5.0, offsets=lift2)) for r in (on, off))
    fresh = ConsistentArm(robot14, "left")
    wrist = b.targets["left_wrist"]
    elbow, R, _ = fresh(wrist.p, b.targets["left_elbow"].p, quat_to_matrix(wrist.q))
    assert np.allclose(a.targets["left_elbow"].p, elbow, rtol=0.0, atol=1e-12)
    assert np.allclose(quat_to_matrix(a.targets["left_wrist"].q), R, rtol=0.0, atol=1e-9)


@pytest.mark.parametrize("placement", ["swivel", "mapped"])
def test_published_velocities_are_differences_of_the_published_targets(robot14, workspace, placement):
    cfg = RetargetConfig(consistent_targets=True, elbow_placement=placement, velocity_tau=0.0)
    ret = Retargeter(cfg, workspace=workspace, robot=robot14)
    ret.step(make_frame(1, 0.0))
    a = ret.step(make_frame(2, 0.1, offsets={"left_wrist": np.array([0.1, 0.0, 0.1])}))
    b = ret.step(make_frame(3, 0.2, offsets={"left_wrist": np.array([0.12, 0.02, 0.13])}))
    e0, e1 = a.targets["left_elbow"], b.targets["left_elbow"]
    assert np.allclose(e1.v, (e1.p - e0.p) / 0.1)
    w0, w1 = a.targets["left_wrist"], b.targets["left_wrist"]
    assert np.allclose(w1.w, pin.log3(quat_to_matrix(w1.q) @ quat_to_matrix(w0.q).T) / 0.1, atol=1e-9)
