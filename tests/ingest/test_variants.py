"""Held-out variants of a real clip (``services.ingest.variants``): its mirror image and the clip played faster."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from services.ingest import load_clip
from services.ingest.publish_cli import add_arguments, load_for_playback
from services.ingest.variants import mirrored, played_at
from shared.mirror import MIRROR
from shared.rotations import quats_to_matrices

CLIP = "dataset-2_wave-left-hand_normal_001.bvh"


@pytest.fixture(scope="module")
def clip(bvh_clips):
    return load_clip(next(p for p in bvh_clips if p.name == CLIP))


def test_the_mirror_image_waves_the_other_hand(clip):
    """Each side's bones become the other side's, reflected through the sagittal plane (positions ``M p``,
    orientations ``M R M``); the operator's waving left hand is the mirror image's right hand; twice is the clip."""
    m = mirrored(clip)
    np.testing.assert_array_equal(m.positions["right_wrist"], clip.positions["left_wrist"] * [1.0, -1.0, 1.0])
    np.testing.assert_array_equal(m.positions["left_elbow"], clip.positions["right_elbow"] * [1.0, -1.0, 1.0])
    np.testing.assert_array_equal(m.valid["right_wrist"], clip.valid["left_wrist"])
    R, Rm = quats_to_matrices(clip.quats["left_wrist"]), quats_to_matrices(m.quats["right_wrist"])
    np.testing.assert_allclose(Rm, MIRROR @ R @ MIRROR, atol=1e-12)
    np.testing.assert_allclose(
        quats_to_matrices(m.root_q), MIRROR @ quats_to_matrices(clip.root_q) @ MIRROR, atol=1e-12
    )
    # the wave: the operator's left wrist travels, the right hangs; in the mirror image the other way round
    travel = {s: np.ptp(clip.positions[f"{s}_wrist"], axis=0).max() for s in ("left", "right")}
    travel_m = {s: np.ptp(m.positions[f"{s}_wrist"], axis=0).max() for s in ("left", "right")}
    assert travel["left"] > 3 * travel["right"], travel
    assert travel_m == {"left": travel["right"], "right": travel["left"]}
    back = mirrored(m)
    for b in clip.positions:
        np.testing.assert_array_equal(back.positions[b], clip.positions[b])
        np.testing.assert_array_equal(back.quats[b], clip.quats[b])
    assert m.meta["mirrored"] and not back.meta["mirrored"]


def test_played_faster_keeps_the_frames(clip):
    """At speed 1.25 the same poses come 1.25 times as often; a speed that is not a finite factor > 0 is refused."""
    fast = played_at(clip, 1.25)
    assert fast.n_frames == clip.n_frames and fast.fps == pytest.approx(1.25 * clip.fps)
    np.testing.assert_allclose(fast.times, clip.times / 1.25)
    assert fast.duration == pytest.approx(clip.duration / 1.25)
    np.testing.assert_array_equal(fast.positions["left_wrist"], clip.positions["left_wrist"])
    assert fast.meta["speed"] == 1.25 and played_at(fast, 2.0).meta["speed"] == 2.5
    for bad in (0, -1.0, float("nan"), float("inf"), True, "2"):
        with pytest.raises(ValueError, match="speed must be a finite number > 0"):
            played_at(clip, bad)


def test_publish_plays_the_mirror_image(bvh_clips, clip):
    """``mimic publish --mirror``: the clip the player gets is the mirror image, after the --start/--end slice."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    path = str(next(p for p in bvh_clips if p.name == CLIP))
    plain = load_for_playback(parser.parse_args([path, "--start", "1.0", "--end", "2.0"]))
    mirror = load_for_playback(parser.parse_args([path, "--start", "1.0", "--end", "2.0", "--mirror"]))
    assert mirror.n_frames == plain.n_frames == 31
    np.testing.assert_array_equal(mirror.positions["right_wrist"], plain.positions["left_wrist"] * [1.0, -1.0, 1.0])
    frame = mirror.frame(0, seq=0)  # what goes on the bus
    np.testing.assert_array_equal(frame.bones["right_wrist"].p, plain.positions["left_wrist"][0] * [1.0, -1.0, 1.0])
