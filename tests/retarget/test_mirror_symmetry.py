"""A robot whose arms are mirror images maps a mirror-image operator onto mirror-image targets.

Before session 21 each arm's workspace cloud and shoulder-centre fit were their own random draws, and the
mirror image of a real wave got wrist targets 0.22 cm off the mirror image of the wave's (every frame)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from services.evaluation.runner import clip_targets
from services.ingest import load_clip
from services.ingest.variants import mirrored
from services.retarget.elbow import ArmGeometry
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.retarget.workspace import pool_mirror_images, sample_workspace
from shared.mirror import MIRROR, arm_joints, mirror_points, mirrored_arms, swap_side
from shared.rotations import quat_to_matrix
from shared.targets import SIDES, TARGET_NAMES

CLIP = "dataset-2_wave-left-hand_normal_001.bvh"


def test_the_g1_workspace_and_arm_geometry_are_mirror_images(workspace, robot14):
    """The G1's arms mirror each other in kinematics and joint ranges, so each arm's cloud is both arms' samples
    and the right arm's cloud, box and shoulder centre are exactly the left's mirror images."""
    assert mirrored_arms(robot14) is not None and workspace.meta["mirror_pooled"]
    for part in ("wrist", "elbow"):
        left, right = f"left_{part}", f"right_{part}"
        assert len(workspace.points[left]) == 2 * workspace.meta["samples"]
        np.testing.assert_array_equal(workspace.points[right], mirror_points(workspace.points[left]))
        np.testing.assert_array_equal(workspace.lower[right][[0, 2]], workspace.lower[left][[0, 2]])
        np.testing.assert_array_equal(workspace.lower[right][1], -workspace.upper[left][1])
    arms = ArmGeometry.measure_arms(robot14)
    np.testing.assert_array_equal(arms["right"].centre, mirror_points(arms["left"].centre))
    assert (arms["right"].upper, arms["right"].fore, arms["right"].reach) == (
        arms["left"].upper,
        arms["left"].fore,
        arms["left"].reach,
    )
    # measured on its own, the right arm's fit is a different draw (the shoulder axes do not meet)
    alone = ArmGeometry.measure(robot14, "right").centre
    assert 1e-5 < np.linalg.norm(alone - arms["right"].centre) < 5e-3


def test_arms_that_are_not_mirror_images_keep_their_own_samples(robot14):
    """A right shoulder whose range is not the mirrored left one: no pooling, each arm its own cloud."""
    k = arm_joints(robot14, "right")[1]
    upper = robot14.upper.copy()
    upper[k] -= 0.3
    lopsided = replace(robot14, upper=upper)
    assert mirrored_arms(lopsided) is None
    points = sample_workspace(lopsided, 200, seed=1, progress=False)
    assert pool_mirror_images(points, lopsided) is False
    assert all(len(points[t]) == 200 for t in TARGET_NAMES)
    assert pool_mirror_images(points, robot14) is True and len(points["left_wrist"]) == 400


@pytest.mark.parametrize("mode", ["bounded", "reach"])
def test_a_mirror_image_operator_gets_mirror_image_targets(bvh_clips, workspace, robot14, mode):
    """A real wave and its mirror image, retargeted with the shipped settings (and the reach mapping): every
    published wrist and elbow target, velocity and wrist orientation of one is the mirror image of the other's
    other side (1.0-3.7 s: the hands stay clear of the trunk, whose meshes are not symmetric; the waving hand
    comes near the head at 0.7, 3.8, 4.5 and 5.1 s, pushed there on 10 frames of the wave and 11 of its mirror
    image since the push poses the whole hand, session 25). Before session 21 the wrists
    were 0.22 cm apart on every frame (each arm its own Monte Carlo draw), 0.03 cm more with the reach mapping."""
    clip = load_clip(next(p for p in bvh_clips if p.name == CLIP)).slice(1.0, 3.7)
    cfg = RetargetConfig(mode=mode)
    a = clip_targets(clip, Retargeter(cfg, workspace=workspace, robot=robot14))
    b = clip_targets(mirrored(clip), Retargeter(cfg, workspace=workspace, robot=robot14))
    assert len(a) == len(b) == clip.n_frames
    for ta, tb in zip(a, b, strict=True):
        for name in TARGET_NAMES:
            x, y = ta.targets[name], tb.targets[swap_side(name)]
            assert x.valid and y.valid
            np.testing.assert_allclose(y.p, MIRROR @ x.p, atol=1e-9)
            np.testing.assert_allclose(y.v, MIRROR @ x.v, atol=1e-7)
            if x.use_rotation:  # each arm's rest orientation comes from an iterative IK: 0.6e-4 / 1.1e-4 apart
                np.testing.assert_allclose(quat_to_matrix(y.q), MIRROR @ quat_to_matrix(x.q) @ MIRROR, atol=3e-4)
    # the mirror image waves its right hand, side to side (measured: 16 cm of y against 2 cm for the left)
    assert {s for s in SIDES if np.ptp([t.targets[f"{s}_wrist"].p[1] for t in b]) > 0.1} == {"right"}
