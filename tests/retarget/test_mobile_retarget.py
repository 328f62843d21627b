"""The retargeter for a mobile robot (services/retarget/mobile.py) on the TITA-PiPER profile and real clips."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from services.ingest.clip import load_clip
from services.retarget.calibration import anthropometric
from services.retarget.mobile import MobileMap, MobileRetargeter
from services.retarget.retargeter import RetargetConfig
from shared.robot.profile import ProfileError
from shared.robot.wheeled import build_wheeled_robot
from tests.support.reach import forward_reach_clip

PROFILE = "models/tita_piper.toml"


@pytest.fixture(scope="module")
def robot():
    return build_wheeled_robot(PROFILE)


def test_the_profile_says_what_drives_what(robot):
    m = MobileMap.from_robot(robot)
    assert m.target == "right_wrist" and m.bone == "right_wrist"
    hand = robot.kin.hand(np.r_[robot.profile.start_base, robot.profile.start_arm])
    assert np.allclose(m.start, hand)
    assert np.all(m.lower < m.start) and np.all(m.start < m.upper)
    # p = start + scale * (h - h_rest), clipped to the box.
    rest = np.array([0.0, -0.2, -0.1])
    p, clipped = m(rest + np.array([0.1, 0.0, 0.05]), rest)
    assert not clipped and np.allclose(p, m.start + m.scale * np.array([0.1, 0.0, 0.05]))
    p, clipped = m(rest + np.array([5.0, 0.0, 5.0]), rest)
    assert clipped and p[0] == m.upper[0] and p[2] == m.upper[2]


@pytest.mark.parametrize(
    "change, words",
    [
        ({"retarget": {}}, "no [retarget] table"),
        (
            {
                "retarget": {
                    "target": "right_wrist",
                    "bone": "right_wrist",
                    "scale": [1, 1],
                    "lower": [0, 0, 0],
                    "upper": [1, 1, 1],
                }
            },
            "scale must be 3",
        ),
        (
            {"retarget": {"target": "nose", "bone": "x", "scale": [1, 1, 1], "lower": [0, 0, 0], "upper": [1, 1, 1]}},
            "not one of",
        ),
        (
            {
                "retarget": {
                    "target": "right_wrist",
                    "bone": "right_wrist",
                    "scale": [1, 1, 1],
                    "lower": [5, 5, 5],
                    "upper": [6, 6, 6],
                }
            },
            "outside the box",
        ),
        (
            {"retarget": {"target": "right_wrist", "scale": [1, 1, 1], "lower": [0, 0, 0], "upper": [1, 1, 1]}},
            "missing field",
        ),
    ],
)
def test_a_bad_retarget_table_is_a_clear_error(robot, change, words):
    bad = dataclasses.replace(robot, profile=dataclasses.replace(robot.profile, **change))
    with pytest.raises(ProfileError, match=words.replace("[", r"\[").replace("]", r"\]")):
        MobileMap.from_robot(bad)


def test_a_real_forward_reach_moves_the_target_forward_from_the_start(robot, bvh_clips):
    clip_path, reach = forward_reach_clip(bvh_clips)
    clip = load_clip(clip_path)
    rt = MobileRetargeter(RetargetConfig(robot=PROFILE), robot=robot)
    xs = []
    for k in range(clip.n_frames):
        out = rt.step(clip.frame(k, k + 1, t0_ns=k + 1))
        assert out is not None, rt.last_reject
        t = out.targets["right_wrist"]
        assert t.valid and not t.use_rotation and list(out.targets) == ["right_wrist"]
        assert np.all(t.p >= rt.map.lower - 1e-12) and np.all(t.p <= rt.map.upper + 1e-12)
        xs.append(t.p[0])
    # Calibrated on the first frame (at rest): the target starts at the gripper's start position ...
    assert abs(xs[0] - rt.map.start[0]) < 1e-9
    # ... and goes forward by the scaled reach (held HOLD_S: the max is at least that).
    assert max(xs) - rt.map.start[0] >= rt.map.scale[0] * reach - 1e-6
    assert rt.counts["frames"] == clip.n_frames


def test_invalid_bone_holds_the_last_target_and_other_sources_are_rejected(robot, bvh_clips):
    clip = load_clip(bvh_clips[0])
    rt = MobileRetargeter(RetargetConfig(robot=PROFILE), robot=robot)
    last = rt.step(clip.frame(0, 1, t0_ns=1)).targets["right_wrist"].p
    f = clip.frame(1, 2, t0_ns=2)
    f.bones["right_wrist"].valid = False
    out = rt.step(f).targets["right_wrist"]
    assert not out.valid and np.allclose(out.p, last) and not out.v.any()
    other = clip.frame(2, 3, t0_ns=3)
    other.source = "someone-else"
    assert rt.step(other) is None and rt.last_reject[0] == "other_source"


def test_uncalibrated_without_auto_calibration_says_so(robot, bvh_clips):
    clip = load_clip(bvh_clips[0])
    rt = MobileRetargeter(RetargetConfig(robot=PROFILE, auto_calibrate=False), robot=robot)
    assert rt.step(clip.frame(0, 1, t0_ns=1)) is None and rt.last_reject[0] == "uncalibrated"
    rt.set_calibration(anthropometric(clip.frame(0, 1)))
    assert rt.step(clip.frame(1, 2, t0_ns=2)) is not None
