"""The embedded demo motions: generated, written by our writer, read back by our reader."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from services.ingest import generate_demo_clips, load_clip
from services.ingest.demo_motion import SKELETON, two_link_ik


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    paths = generate_demo_clips(tmp_path_factory.mktemp("demo"))
    return {p.stem: load_clip(p) for p in paths}


def _flexion(clip, side):
    u = clip.positions[f"{side}_elbow"] - clip.positions[f"{side}_shoulder"]
    v = clip.positions[f"{side}_wrist"] - clip.positions[f"{side}_elbow"]
    return np.degrees(np.arccos(np.sum(u * v, 1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)))


def test_both_motions_read_back(demo):
    assert set(demo) == {"box_lift", "ellipse"}
    for clip in demo.values():
        assert clip.fps == 60.0 and clip.duration > 4.0
        assert clip.meta["skeleton_map"] == "cmu" and clip.meta["units"] == "cm"
        for b in ("left_wrist", "right_wrist", "left_elbow", "right_elbow", "left_hand", "head"):
            assert clip.valid[b].all(), b


def test_realistic_proportions(demo):
    off = {name: np.linalg.norm(o) / 100 for name, _p, o, _e in SKELETON}
    assert 0.26 < off["LeftForeArm"] < 0.34  # upper arm [m]
    assert 0.22 < off["LeftHand"] < 0.30  # forearm [m]
    clip = demo["box_lift"]
    top = clip.world_positions("head")[:, 2] + 0.18
    assert 1.6 < top.max() < 1.9  # standing height


def test_bone_lengths_constant(demo):
    for clip in demo.values():
        for a, b in (("left_shoulder", "left_elbow"), ("right_elbow", "right_wrist"), ("right_wrist", "right_hand")):
            d = np.linalg.norm(clip.positions[a] - clip.positions[b], axis=1)
            assert np.ptp(d) < 1e-4


def test_box_lift_elbows_out_and_box_rises(demo):
    clip = demo["box_lift"]
    held = (clip.times >= 1.0) & (clip.times <= clip.duration - 1.0)  # between reaching for it and letting go
    lw, rw = clip.positions["left_wrist"][held], clip.positions["right_wrist"][held]
    assert np.ptp(lw[:, 2]) > 0.25  # the box goes up ~28 cm
    assert np.allclose(lw[:, 1] - rw[:, 1], 0.34, atol=0.01)  # both hands keep the box width
    assert np.all(lw[:, 0] > 0.2)  # box held in front
    for side, sign in (("left", 1), ("right", -1)):
        el, sh, wr = (clip.positions[f"{side}_{b}"][held] for b in ("elbow", "shoulder", "wrist"))
        assert np.all(sign * (el[:, 1] - sh[:, 1]) > 0.05)  # elbows out beyond the shoulders
        assert np.all(sign * (el[:, 1] - wr[:, 1]) > 0.1)
        f = _flexion(clip, side)[held]
        assert f.min() > 45 and f.max() < 120


def test_motions_start_and_end_at_rest_so_the_demo_loop_is_continuous(demo):
    # The demo plays box_lift, ellipse, box_lift, ... : each motion's last frame must be the next one's first
    # (the box lift used to end with the box held low, 13 cm from the ellipse's first frame).
    clips = list(demo.values())
    for a, b in zip(clips, clips[1:] + clips[:1]):
        for part in ("left_wrist", "right_wrist", "left_elbow", "right_elbow"):
            gap = np.linalg.norm(a.world_positions(part)[-1] - b.world_positions(part)[0])
            assert gap < 0.005, (part, gap)
        for clip in (a, b):  # and the arms hang there: wrists beside the hips, below the elbows
            wr, el = clip.world_positions("right_wrist"), clip.world_positions("right_elbow")
            assert wr[0, 2] < el[0, 2] - 0.2 and wr[-1, 2] < el[-1, 2] - 0.2


def test_ellipse_is_drawn(demo):
    clip = demo["ellipse"]
    w = clip.positions["right_wrist"]
    mid = (clip.times > 1.2) & (clip.times < clip.duration - 1.2)
    y, z = w[mid, 1], w[mid, 2]
    assert np.ptp(y) == pytest.approx(0.30, abs=0.02) and np.ptp(z) == pytest.approx(0.20, abs=0.02)
    cy, cz = (y.max() + y.min()) / 2, (z.max() + z.min()) / 2
    r = ((y - cy) / 0.15) ** 2 + ((z - cz) / 0.10) ** 2
    assert np.allclose(r, 1.0, atol=0.08)  # on the ellipse, not just in its box
    assert np.ptp(w[mid, 0]) < 0.01  # in a vertical plane in front of the body
    assert np.ptp(clip.positions["left_wrist"], axis=0).max() < 1e-6  # left arm hangs still


def test_two_link_ik_reaches():
    S = np.zeros((5, 3))
    W = np.array([[30, 0, 20], [10, -20, 30], [0, 0, 50], [40, 10, 0], [20, 20, 20]], float)
    E = two_link_ik(S, W, 29.0, 26.0, np.array([0.0, 0.0, -1.0]))
    assert np.allclose(np.linalg.norm(E - S, axis=1), 29.0)
    assert np.allclose(np.linalg.norm(W - E, axis=1), 26.0)


def test_cli_regenerates(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "services.cli", "demo-motion", str(tmp_path / "m")],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    summary = json.loads(out.stdout)["demo_motion"]
    assert [s["path"].rsplit("/", 1)[-1] for s in summary] == ["box_lift.bvh", "ellipse.bvh"]
    assert all(s["frames"] > 200 for s in summary)
