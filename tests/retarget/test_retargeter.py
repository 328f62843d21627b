"""Retargeter.step on synthetic HumanFrames: headers, eq. (4), validity, order, velocities, modes."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import make_frame, random_quat

from services.retarget.calibration import anthropometric
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.messages import TaskTargets
from shared.rotations import matrix_to_quat, quat_to_matrix
from shared.targets import TARGET_NAMES, WRISTS, side_of

#: These tests check seed 000's eqs. (1)-(4) as written: per-axis elbows, eq. 4 against the rest pose.
#: The product defaults (swivel elbows, forearm-relative orientation) are covered in test_elbow.py.
#: The per-axis box mapping ("bounded") is what eqs. 1-3 describe; the default "reach" mode is in test_reach.py.
PAPER = {"mode": "bounded", "elbow_placement": "mapped", "orientation_reference": "rest"}


@pytest.fixture()
def make(robot14, workspace):
    def _make(**cfg):
        cal = cfg.pop("calibration", None)
        return Retargeter(RetargetConfig(**{**PAPER, **cfg}), calibration=cal, workspace=workspace, robot=robot14)

    return _make


def test_header_copied_and_message_valid(make):
    r = make()
    out = r.step(make_frame(41, 12.5, t0=987654321))
    assert (out.hdr.seq, out.hdr.stamp, out.hdr.t0) == (41, 12.5, 987654321)
    assert out.mode == "bounded"
    back = TaskTargets.decode(out.encode())
    assert set(back.targets) == set(TARGET_NAMES)
    assert back.targets["left_wrist"].use_rotation and not back.targets["left_elbow"].use_rotation
    assert r.calibration.source == "anthropometric"


def test_operator_at_rest_gives_robot_rest_orientation(make, robot14):
    rng = np.random.default_rng(5)
    quats = {b: random_quat(rng) for b in TARGET_NAMES}
    r = make(elbow_rotation=True)
    out = r.step(make_frame(0, 0.0, quats=quats))  # auto calibration: this frame is the rest
    rest = robot14.frame_poses(robot14.q_rest, names=TARGET_NAMES)
    for t in TARGET_NAMES:
        np.testing.assert_allclose(quat_to_matrix(out.targets[t].q), rest[t][1], atol=1e-9)
    # the same rest again later (new frame) still maps to the robot rest orientation
    out = r.step(make_frame(1, 0.1, quats=quats))
    for t in TARGET_NAMES:
        np.testing.assert_allclose(quat_to_matrix(out.targets[t].q), rest[t][1], atol=1e-9)


def test_operator_rotation_is_reproduced_in_the_pelvis_frame(make, robot14):
    rng = np.random.default_rng(6)
    q_rest = random_quat(rng)
    r = make()
    r.step(make_frame(0, 0.0, quats={"left_wrist": q_rest}))
    delta = pin.exp3(np.array([0.3, -0.5, 0.8]))
    q_new = matrix_to_quat(delta @ quat_to_matrix(q_rest))
    out = r.step(make_frame(1, 0.1, quats={"left_wrist": q_new}))
    R_U_rest = robot14.frame_poses(robot14.q_rest, names=("left_wrist",))["left_wrist"][1]
    np.testing.assert_allclose(quat_to_matrix(out.targets["left_wrist"].q), delta @ R_U_rest, atol=1e-9)


def test_rest_maps_to_eq1_and_motion_scales_per_axis(make, workspace):
    # eqs. 1-3 alone: without the push of targets off the trunk (it moves this hand, raised towards the chest)
    r = make(mode="paper", trunk_clearance=False)
    out = r.step(make_frame(0, 0.0))
    cal = r.calibration
    for t in TARGET_NAMES:
        lo, hi = workspace.lower[t], workspace.upper[t]
        ratio = (cal.rest[t] - cal.lower[t]) / (cal.upper[t] - cal.lower[t])
        np.testing.assert_allclose(out.targets[t].p, lo + ratio * (hi - lo), atol=1e-12)
    dH = np.array([0.1, -0.05, 0.2])
    out2 = r.step(make_frame(1, 0.1, offsets={"left_wrist": dH}))
    M = (workspace.upper["left_wrist"] - out.targets["left_wrist"].p) / (
        cal.upper["left_wrist"] - cal.rest["left_wrist"]
    )
    np.testing.assert_allclose(out2.targets["left_wrist"].p - out.targets["left_wrist"].p, M * dH, atol=1e-12)
    np.testing.assert_allclose(out2.targets["right_wrist"].p, out.targets["right_wrist"].p)


def test_invalid_or_missing_bones_give_invalid_targets_holding_the_last_pose(make):
    r = make()
    a = r.step(make_frame(0, 0.0))
    b = r.step(make_frame(1, 0.1, invalid=("left_wrist",), drop=("right_elbow",)))
    assert not b.targets["left_wrist"].valid and not b.targets["right_elbow"].valid
    assert b.targets["right_wrist"].valid and b.targets["left_elbow"].valid
    np.testing.assert_allclose(b.targets["left_wrist"].p, a.targets["left_wrist"].p)
    assert np.all(b.targets["left_wrist"].v == 0) and np.all(b.targets["left_wrist"].w == 0)
    assert r.counts["invalid_left_wrist"] == 1 and r.counts["invalid_right_elbow"] == 1
    c = r.step(make_frame(2, 0.2, offsets={"left_wrist": np.array([0.0, 0.0, 0.1])}))
    assert c.targets["left_wrist"].valid
    assert np.all(c.targets["left_wrist"].v == 0)  # no finite difference across the invalid frame


def test_no_calibration_without_valid_arm_bones(make):
    r = make(one_arm_after=2)
    assert r.step(make_frame(0, 0.0, invalid=("left_shoulder", "right_wrist"))) is None
    assert r.last_reject[0] == "uncalibrated"
    assert r.step(make_frame(1, 0.1, invalid=("left_shoulder",))) is None  # one arm: wait for both
    assert r.step(make_frame(2, 0.2)) is not None and r.calibration.source == "anthropometric"
    # a one-armed source is accepted after `one_arm_after` frames, the other arm mirrored
    r = make(one_arm_after=2)
    outs = [r.step(make_frame(i, i / 10, drop=("left_shoulder", "left_elbow", "left_wrist"))) for i in range(4)]
    assert [o is None for o in outs] == [True, True, False, False]
    assert "mirrored" in r.calibration.source
    assert not outs[-1].targets["left_wrist"].valid and outs[-1].targets["right_wrist"].valid
    r2 = make(auto_calibrate=False)
    assert r2.step(make_frame(0, 0.0)) is None and r2.rejects["uncalibrated"] == 1


def test_out_of_order_frames_rejected_with_reasons_then_resync(make):
    r = make(resync_after=3)
    assert r.step(make_frame(10, 1.0)) is not None
    assert r.step(make_frame(10, 1.1)) is None and r.last_reject[0] == "duplicate_seq"
    assert r.step(make_frame(9, 1.2)) is None and r.last_reject[0] == "seq_backwards"
    # third bad frame in a row (stamp not after 1.0): the source counts as restarted and is followed
    assert r.step(make_frame(11, 1.0)) is not None
    assert r.counts["resync"] == 1
    assert r.rejects == {"duplicate_seq": 1, "seq_backwards": 1}
    r = make()
    r.step(make_frame(1, 1.0))
    assert r.step(make_frame(2, 0.5)) is None and r.last_reject[0] == "time_backwards"
    assert r.step(make_frame(3, 1.0)) is None and r.last_reject[0] == "time_backwards"
    assert r.step(make_frame(4, 1.05)) is not None and r.last_reject is None


def test_velocities_follow_the_mapped_motion(make):
    r = make(mode="paper", velocity_tau=0.02)
    dt, vH = 1 / 60, np.array([0.2, 0.1, 0.3])
    r.step(make_frame(0, 0.0))
    M = r._pos_map["left_wrist"].M_up
    for i in range(1, 60):
        out = r.step(make_frame(i, i * dt, offsets={"left_wrist": vH * i * dt}))
    np.testing.assert_allclose(out.targets["left_wrist"].v, M * vH, rtol=1e-6)
    np.testing.assert_allclose(out.targets["right_wrist"].v, 0.0, atol=1e-12)
    # angular velocity of a steady rotation about z at 1 rad/s
    r = make(velocity_tau=0.0)
    for i in range(5):
        q = matrix_to_quat(pin.exp3(np.array([0.0, 0.0, 1.0 * i * dt])))
        out = r.step(make_frame(i, i * dt, quats={"right_wrist": q}))
    np.testing.assert_allclose(out.targets["right_wrist"].w, [0.0, 0.0, 1.0], atol=1e-9)


@pytest.mark.parametrize("push", [False, True], ids=["no push", "trunk push"])
def test_bounded_mode_keeps_wild_motion_in_the_box(make, workspace, push):
    """Every target in the box; with the trunk push (default) a wrist target leaves it only where the push moved
    it, and then it is at the push's clearance off the trunk (between the fast and the full one)."""
    r = make(trunk_clearance=push)
    rng = np.random.default_rng(2)
    r.step(make_frame(0, 0.0))
    pushed_out = 0
    for i in range(1, 200):
        offs = {b: rng.uniform(-1.5, 1.5, 3) for b in TARGET_NAMES}
        out = r.step(make_frame(i, i / 30, offsets=offs))
        for t in TARGET_NAMES:
            p = out.targets[t].p
            if workspace.contains(t, p):
                continue
            assert push and t in WRISTS, t
            d = r.trunk.nearest(side_of(t), p, quat_to_matrix(out.targets[t].q))[0]
            assert r.trunk.fast_clearance - 5e-4 < d < r.trunk.clearance + 5e-4, (t, d)
            pushed_out += 1
    assert r.counts["clamped_left_wrist"] > 0
    assert (pushed_out > 0) == push  # (the push ran, and moved some targets out of the box)


def test_incremental_mode_starts_at_robot_rest_and_adds_deltas(make, robot14, workspace):
    r = make(mode="incremental", incremental_scale=0.5)
    out0 = r.step(make_frame(0, 0.0))
    rest = robot14.frame_poses(robot14.q_rest, names=TARGET_NAMES)
    for t in TARGET_NAMES:
        np.testing.assert_allclose(out0.targets[t].p, np.clip(rest[t][0], workspace.lower[t], workspace.upper[t]))
    out1 = r.step(make_frame(1, 0.1, offsets={"left_elbow": np.array([0.02, 0.0, 0.04])}))
    np.testing.assert_allclose(
        out1.targets["left_elbow"].p - out0.targets["left_elbow"].p, [0.01, 0.0, 0.02], atol=1e-12
    )


def test_explicit_calibration_and_recalibration(make):
    cal = anthropometric(make_frame(0, 0.0, offsets={"left_wrist": np.array([0.0, 0.0, -0.05])}))
    r = make(calibration=cal)
    out = r.step(make_frame(0, 0.0))
    assert r.calibration is cal
    r.request_recalibration()
    out2 = r.step(make_frame(1, 0.1))
    assert r.calibration is not cal and r.calibration.source == "anthropometric"
    assert not np.allclose(out.targets["left_wrist"].p, out2.targets["left_wrist"].p)


def test_bad_config_is_a_clear_error():
    with pytest.raises(ValueError, match="known"):
        RetargetConfig(mode="fancy")


def _from(source: str, seq: int, stamp: float, t0: int):
    f = make_frame(seq, stamp, t0=t0)
    return type(f)(f.hdr, source, f.root, f.bones)


def test_two_sources_follow_one_and_say_so(make):
    """Two publishers at once: the first is followed, the other rejected (``other_source``) until the
    followed one is silent for ``source_timeout``; ``source=`` chooses one explicitly."""
    r = make()
    ms = 1_000_000
    outs = []
    for i in range(20):  # interleaved, 60 Hz each
        outs.append(r.step(_from("a", i, i / 60, 17 * ms * i + 1)))
        outs.append(r.step(_from("b", 100 + i, 5 + i / 60, 17 * ms * i + 2)))
    assert all(o is not None for o in outs[0::2]) and all(o is None for o in outs[1::2])
    assert r.rejects["other_source"] == 20 and r.counts["new_source"] == 0
    # "a" falls silent: after the timeout "b" is followed, as a new stream
    later = 17 * ms * 20 + int(1.5e9)
    assert r.step(_from("b", 200, 6.0, later)) is not None and r.counts["new_source"] == 1
    assert r.step(_from("a", 21, 21 / 60, later + ms)) is None and r.last_reject[0] == "other_source"
    # explicit choice: "b" only, even when "a" came first
    r = make(source="b")
    assert r.step(_from("a", 0, 0.0, 1)) is None and r.last_reject[0] == "other_source"
    assert r.step(_from("b", 0, 0.0, 2)) is not None


def test_a_source_chosen_at_run_time_is_followed_and_the_choice_can_be_dropped(make, caplog):
    """follow_source() (the ``keys.retarget_source`` query) switches from the first-seen source at once."""
    r = make()
    ms = 1_000_000
    for i in range(10):
        assert r.step(_from("a", i, i / 60, 17 * ms * i + 1)) is not None
        assert r.step(_from("b", 100 + i, 5 + i / 60, 17 * ms * i + 2)) is None
    assert r.followed_source == "a" and r.sources_seen == {"a": 10, "b": 10}
    with caplog.at_level("INFO"):
        r.follow_source("b")
    assert r.followed_source == "b" and "following source 'b', chosen explicitly" in caplog.text
    t = 17 * ms * 10
    assert r.step(_from("a", 10, 10 / 60, t + 1)) is None and r.last_reject[0] == "other_source"
    assert r.step(_from("b", 110, 5 + 10 / 60, t + 2)) is not None and r.counts["new_source"] == 1
    assert "ignoring frames of source 'a'" in caplog.text  # the newly ignored one is named
    r.follow_source("")  # no choice: the followed one stays until it is silent
    assert r.followed_source == "b"
    assert r.step(_from("a", 11, 11 / 60, t + 3)) is None


def test_a_restarted_source_is_followed_from_its_first_frame(make):
    """The same sender run again (seq from 0, frames made later): no frame of the second run is lost."""
    r = make()
    for i in range(300):
        assert r.step(make_frame(i, i / 60, t0=1_000 + i)) is not None
    assert r.step(make_frame(0, 0.0, t0=10_000)) is not None
    assert r.counts["resync"] == 1 and not r.rejects
