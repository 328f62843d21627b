"""The real Bandai Namco clips: loading, bone lengths, elbow flexion, frames."""

from __future__ import annotations

import re

import numpy as np
import pytest

from services.ingest import load_clip
from services.ingest.bvh import parse_bvh
from services.ingest.rotations import Y_UP_TO_Z_UP, quats_to_matrices

SEGMENTS = [
    ("pelvis", "spine"),
    ("spine", "chest"),
    ("chest", "neck"),
    ("neck", "head"),
    *[(f"{s}_{a}", f"{s}_{b}") for s in ("left", "right") for a, b in
      (("clavicle", "shoulder"), ("shoulder", "elbow"), ("elbow", "wrist"), ("wrist", "hand"))],
]  # fmt: skip


@pytest.fixture(scope="module")
def clips(bvh_clips):
    return {p.name: load_clip(p) for p in bvh_clips}


def _flexion(clip, side: str) -> np.ndarray:
    """Elbow flexion [deg]: angle between the upper-arm and forearm vectors (0 = straight)."""
    u = clip.positions[f"{side}_elbow"] - clip.positions[f"{side}_shoulder"]
    v = clip.positions[f"{side}_wrist"] - clip.positions[f"{side}_elbow"]
    c = np.sum(u * v, axis=1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def test_all_bandai_clips_load(bvh_clips, clips, mocap_sources):
    assert sorted(p.name for p in bvh_clips) == sorted(mocap_sources.bvh_names())
    for name, clip in clips.items():
        assert clip.meta["skeleton_map"] == "bandai", name
        assert clip.meta["units"] == "cm" and clip.meta["up"] == "y", name
        assert clip.meta["position_mode"] == "replace", name  # the Bandai 6-channel quirk
        assert clip.fps == 30.0
        assert clip.n_frames > 40
        for b in ("pelvis", "spine", "chest", "neck", "head", "left_wrist", "right_elbow"):
            assert clip.valid[b].all(), (name, b)


def test_frame_counts_match_sources(mocap_sources, clips):
    for name, clip in clips.items():
        assert clip.n_frames == mocap_sources.frames(name), name


def test_bone_lengths_constant_within_1mm(clips):
    for name, clip in clips.items():
        for a, b in SEGMENTS:
            if a in clip.positions and b in clip.positions:
                d = np.linalg.norm(clip.positions[a] - clip.positions[b], axis=1)
                assert d.max() - d.min() < 1e-3, (name, a, b, d.max() - d.min())
                assert 0.02 < d.mean() < 0.6, (name, a, b, d.mean())


def test_elbow_flexion_matches_sources(mocap_sources, clips):
    for name, clip in clips.items():
        sec = mocap_sources.section(name)
        for side, S in (("left", "L"), ("right", "R")):
            lo, hi = map(float, re.search(rf"{S} elbow flex (\d+)-(\d+) deg", sec).groups())
            f = _flexion(clip, side)
            assert abs(f.min() - lo) <= 5.0 and abs(f.max() - hi) <= 5.0, (name, side, f.min(), f.max(), lo, hi)


def test_wrist_height_above_shoulder_matches_sources(mocap_sources, clips):
    """World Z-up conversion: the max wrist height over the shoulder, as SOURCES.md measured it."""
    for name, clip in clips.items():
        sec = mocap_sources.section(name)
        for side, S in (("left", "L"), ("right", "R")):
            ref = float(re.search(rf"max {S} wrist (?:height )?above {S} shoulder (-?[\d.]+) cm", sec).group(1))
            dz = clip.world_positions(f"{side}_wrist")[:, 2] - clip.world_positions(f"{side}_shoulder")[:, 2]
            assert abs(100 * dz.max() - ref) < 1.0, (name, side, 100 * dz.max(), ref)


def test_pelvis_frame_axes(clips, mocap_sources):
    """x forward, y left, z up for the operator; the pelvis tilts past SOURCES.md's bound (forward)
    exactly in the clips it names (a bow), and stays within it in every other clip."""
    limit, tilted = mocap_sources.pelvis_tilt_over()
    assert tilted and tilted <= set(clips)
    for name, clip in clips.items():
        # right -> left shoulder along +y: the torso twists on the pelvis by at most 35 deg (kick), never 60
        across = clip.positions["left_shoulder"] - clip.positions["right_shoulder"]
        assert np.all(across[:, 1] > 0.5 * np.linalg.norm(across, axis=1)), name
        assert np.all(clip.positions["head"][:, 2] > 0.3), name
        R = quats_to_matrices(clip.root_q)
        tilt = np.degrees(np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0)))  # pelvis z axis from world up
        if name in tilted:
            k = int(np.argmax(tilt))
            assert tilt[k] > limit and R[k, 2, 0] < 0.0, (name, tilt[k])  # forward: the x axis dips
        else:
            assert tilt.max() < limit, (name, tilt.max())
        assert np.allclose(clip.positions["pelvis"], 0.0) and clip.valid["pelvis"].all()


def test_forward_is_where_the_hands_reach(clips):
    """In the guide and happy bye-bye clips the right hand goes out in front: +x in the pelvis frame."""
    for name in ("dataset-1_guide_active_001.bvh", "dataset-1_byebye_happy_001.bvh"):
        w = clips[name].positions["right_wrist"]
        assert w[:, 0].max() > 0.3, (name, w[:, 0].max())
        assert w[:, 0].min() > -0.25, name


def _rot(axis: str, deg: np.ndarray) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def test_root_frame_conversion_against_direct_world_fk(bvh_clips):
    """Bones in the pelvis frame equal (T_w^h)^-1 T_w^e from an independent per-frame FK in the world."""
    path = bvh_clips[0]
    clip = load_clip(path)
    data = parse_bvh(path)
    names = data.names
    for t in (0, clip.n_frames // 2, clip.n_frames - 1):
        Rg, pg = {}, {}
        for j in data.joints:
            vals = data.motion[t, j.first_channel : j.first_channel + len(j.channels)]
            R = np.eye(3)
            trans = j.offset.copy()
            for c, v in zip(j.channels, vals):
                if c.endswith("rotation"):
                    R = R @ _rot(c[0], v)
                else:
                    trans["XYZ".index(c[0])] = v  # Bandai: position channels are the local translation
            if j.parent < 0:
                Rg[j.name], pg[j.name] = R, trans
            else:
                par = names[j.parent]
                Rg[j.name], pg[j.name] = Rg[par] @ R, pg[par] + Rg[par] @ trans
        world = {n: 0.01 * Y_UP_TO_Z_UP @ p for n, p in pg.items()}
        R_root = quats_to_matrices(clip.root_q[t])
        assert np.allclose(clip.root_p[t], world["Hips"], atol=1e-9)
        for bone, joint in (("left_elbow", "LowerArm_L"), ("right_wrist", "Hand_R"), ("head", "Head")):
            expect = R_root.T @ (world[joint] - world["Hips"])
            assert np.allclose(clip.positions[bone][t], expect, atol=1e-9), (bone, t)
            # orientation: joint frame in the world, expressed in the pelvis frame
            Rw = Y_UP_TO_Z_UP @ Rg[joint]
            assert np.allclose(quats_to_matrices(clip.quats[bone][t]), R_root.T @ Rw, atol=1e-9)


def test_frame_message_roundtrip(clips):
    from shared.messages import HumanFrame

    clip = next(iter(clips.values()))
    f = clip.frame(5, seq=42, t0_ns=123)
    g = HumanFrame.decode(f.encode())
    assert g.hdr.seq == 42 and g.hdr.t0 == 123 and g.hdr.stamp == pytest.approx(clip.times[5])
    assert set(g.bones) == set(clip.bones)
    assert np.allclose(g.bones["left_wrist"].p, clip.positions["left_wrist"][5])
    assert np.allclose(g.root.q, clip.root_q[5])
