"""Wrist-only sources (VR controllers) in the retargeter, and the operator upper arm it publishes."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import make_frame

from services.ingest import load_clip
from services.retarget.calibration import CalibrationError, from_wrists
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.retarget.upper_arm import UpperArmSolver
from shared.messages import TaskTargets
from shared.robot.profile import upper_arm_frame
from shared.rotations import quat_to_matrix
from shared.wrist_only import is_wrist_only, wrists_only

ARM = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow")


def test_wrist_only_frame_calibrates_and_gives_wrists_only(robot14, workspace):
    ret = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    frame = make_frame(1, 0.0, drop=ARM)
    assert is_wrist_only(frame)
    out = ret.step(frame)
    assert out is not None, ret.last_reject
    assert ret.calibration.source.startswith("wrists")
    assert out.targets["left_wrist"].valid and out.targets["right_wrist"].valid
    assert not out.targets["left_elbow"].valid and not out.targets["right_elbow"].valid
    assert out.upper_arms == {}
    # The hands move: the wrist targets follow, the elbows stay invalid; the message is valid on the wire.
    moved = ret.step(make_frame(2, 1 / 30, offsets={"left_wrist": np.array([0.1, 0.0, 0.15])}, drop=ARM))
    assert np.linalg.norm(moved.targets["left_wrist"].p - out.targets["left_wrist"].p) > 0.05
    back = TaskTargets.decode(moved.encode())
    assert not back.targets["left_elbow"].valid and back.upper_arms == {}


def test_from_wrists_uses_the_given_arm_length_and_refuses_nonsense():
    frame = make_frame(1, 0.0, drop=ARM)
    short, long = from_wrists(frame, arm_length=0.45), from_wrists(frame, arm_length=0.65)
    span = {c.arm_length["left"]: c.upper["left_wrist"][2] - c.lower["left_wrist"][2] for c in (short, long)}
    assert span[0.65] > span[0.45] + 0.3  # the box is the sphere the assumed arm sweeps
    with pytest.raises(CalibrationError, match="arm length"):
        from_wrists(frame, arm_length=0.0)
    with pytest.raises(CalibrationError, match="no wrist"):
        from_wrists(make_frame(1, 0.0, drop=(*ARM, "left_wrist", "right_wrist")))


def test_upper_arm_solver_recovers_the_link_orientation_of_a_posture(robot14):
    """Elbow and wrist frames of a robot posture (wrist joints at zero) give back its upper-arm link
    orientation, followed frame to frame (warm start)."""
    link = upper_arm_frame(robot14.profile, "left")
    solver = UpperArmSolver(robot14, "left", link)
    q = solver.q0.copy()
    arm = solver.joints
    worst = 0.0
    for k in range(40):
        q[arm] = solver.q0[arm] + 0.5 * np.sin(0.15 * k + np.arange(4))
        # Elbow kept below 1.2 rad: folded further, the G1's forearm lines up with the shoulder-yaw
        # axis and the twist no longer moves the wrist (0.06 rad of yaw per 0.1 mm there).
        q[arm[3]] = 0.85 + 0.3 * np.sin(0.15 * k + 3)
        poses = robot14.frame_poses(q, names=("left_elbow", "left_wrist", link))
        R = solver(poses["left_elbow"][0], poses["left_wrist"][0])
        worst = max(worst, np.linalg.norm(pin.log3(R @ poses[link][1].T)))
    assert worst < np.radians(0.5)


def test_real_clip_publishes_upper_arms_and_wrist_only_drops_them(bvh_clips, robot14, workspace):
    clip = load_clip(bvh_clips[0])
    full = Retargeter(RetargetConfig(upper_arms=True), workspace=workspace, robot=robot14)
    wo = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
    link = {s: upper_arm_frame(robot14.profile, s) for s in ("left", "right")}
    n = min(clip.n_frames, 60)
    gaps = []
    for i in range(n):
        f = clip.frame(i, seq=i)
        a, b = full.step(f), wo.step(wrists_only(f))
        assert set(a.upper_arms) == {"left", "right"}
        assert b.upper_arms == {} and not b.targets["left_elbow"].valid
        # R_m is the link orientation of a posture whose elbow sits on the published elbow target.
        for s in ("left", "right"):
            sol = full.upper_arm_maps[s]
            R = quat_to_matrix(a.upper_arms[s])
            assert np.linalg.norm(pin.log3(R @ robot14.frame_poses(sol.q, names=(link[s],))[link[s]][1].T)) < 1e-6
            gaps.append(np.linalg.norm(robot14.frame_poses(sol.q)[f"{s}_elbow"][0] - full._placed[s][0]))
    # 5-6 mm: the swivel elbow sits on a sphere about the least-squares shoulder centre, which the
    # G1's non-intersecting shoulder axes reach to about half a centimetre (see retarget/elbow.py).
    assert np.median(gaps) < 0.007


def test_readme_wrist_only_wording_matches_the_code():
    """README's wrist-only bullet: the default arm length, the one-hand wait and the flag it names."""
    import re

    from services.cli import build_parser
    from services.retarget.calibration import DEFAULT_ARM_LENGTH
    from services.retarget.retargeter import RetargetConfig
    from shared.paths import REPO_ROOT

    text = (REPO_ROOT / "README.md").read_text()
    bullet = text[text.index("- **A wrist-only source**") :].split("\n- ", 1)[0]
    assert f"(default {DEFAULT_ARM_LENGTH:g} m;" in bullet
    assert f"one hand alone: after {RetargetConfig().one_arm_after} frames" in bullet
    length = float(re.search(r"mimic retarget --arm-length (\d\.\d+)`", bullet).group(1))
    args = build_parser("retarget").parse_args(["retarget", "--arm-length", str(length)])
    assert args.arm_length == length and RetargetConfig().arm_length == DEFAULT_ARM_LENGTH
