"""Monte Carlo workspace: independent FK check, shrink, cache."""

from __future__ import annotations

import numpy as np
import pytest

from services.retarget.workspace import Shrink, Workspace, load_workspace, sample_workspace
from shared.robot.mujoco_model import build_mujoco_robot
from shared.robot.profile import DEFAULT_PROFILE
from shared.targets import TARGET_NAMES


def test_samples_match_mujoco_forward_kinematics(robot14):
    pts = sample_workspace(robot14, samples=200, seed=7, progress=False)
    # the same configurations, replayed through MuJoCo (an independent FK implementation)
    qs = robot14.random_configurations(200, np.random.default_rng(7))
    mj = build_mujoco_robot(robot14.profile, joint_names=robot14.joint_names)
    for i in (0, 57, 199):
        mj.set_q(qs[i])
        for t in TARGET_NAMES:
            np.testing.assert_allclose(pts[t][i], mj.frame_pose(t)[0], atol=1e-9)


def test_default_box_is_the_5_95_percentile_box(workspace):
    assert workspace.meta["samples"] == 12_000
    for t in TARGET_NAMES:
        pts = workspace.points[t]
        assert pts.shape == (24_000, 3)  # each arm's samples and the other arm's, mirrored (the G1's arms mirror)
        inside = np.mean((pts >= workspace.lower[t]) & (pts <= workspace.upper[t]), axis=0)
        np.testing.assert_allclose(inside, 0.9, atol=0.002)
        assert np.all(workspace.raw_lower[t] < workspace.lower[t])
        assert np.all(workspace.upper[t] < workspace.raw_upper[t])
    # left and right arms are mirror images (y flips)
    np.testing.assert_allclose(workspace.lower["left_wrist"][[0, 2]], workspace.lower["right_wrist"][[0, 2]], atol=0.01)
    np.testing.assert_allclose(workspace.upper["left_wrist"][1], -workspace.lower["right_wrist"][1], atol=0.01)


def test_shrink_forms(workspace):
    ws = Workspace(dict(workspace.points), shrink=Shrink(0.0, 0.03))
    for t in TARGET_NAMES:
        np.testing.assert_allclose(ws.lower[t], ws.raw_lower[t] + 0.03)
        np.testing.assert_allclose(ws.upper[t], ws.raw_upper[t] - 0.03)
    assert Shrink.parse("0.05") == Shrink(0.05, 0.0)
    assert Shrink.parse("0.03m") == Shrink(0.0, 0.03)
    assert Shrink.parse("0.1, 0.01m") == Shrink(0.1, 0.01)
    with pytest.raises(ValueError, match="expected"):
        Shrink.parse("5%")
    with pytest.raises(ValueError, match=r"\[0, 0.5\)"):
        Shrink.parse("0.7")
    with pytest.raises(ValueError, match="empty workspace box"):
        Workspace(dict(workspace.points), shrink=Shrink(0.0, 0.5))


def test_cache_round_trip_and_env_override(robot14, tmp_path, monkeypatch):
    monkeypatch.setenv("MIMIC_CACHE_DIR", str(tmp_path))
    a = load_workspace(robot14.profile, samples=500, seed=3, robot=robot14, progress=False)
    files = list(tmp_path.glob(f"workspace_{DEFAULT_PROFILE}_500_3_*.npz"))
    assert len(files) == 1 and not a.meta["cached"]
    b = load_workspace(robot14.profile, samples=500, seed=3, shrink=Shrink(0.1), progress=False)
    assert b.meta["cached"]
    for t in TARGET_NAMES:
        np.testing.assert_array_equal(a.points[t], b.points[t])
        assert np.all(b.upper[t] - b.lower[t] < a.upper[t] - a.lower[t])  # shrink applied on load
    c = load_workspace(robot14.profile, samples=500, seed=4, robot=robot14, progress=False)
    assert not c.meta["cached"] and not np.array_equal(c.points["left_wrist"], a.points["left_wrist"])
    files[0].write_bytes(b"garbage")
    d = load_workspace(robot14.profile, samples=500, seed=3, robot=robot14, progress=False)
    assert not d.meta["cached"]
    np.testing.assert_array_equal(d.points["left_wrist"], a.points["left_wrist"])
