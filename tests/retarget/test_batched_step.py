"""The batched retarget step publishes what the former per-target step did (tests/retarget/per_target_oracle.py)."""

from __future__ import annotations

import numpy as np
import pytest

from services.ingest.clip import load_clip
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.targets import TARGET_NAMES
from tests.retarget.conftest import make_frame
from tests.retarget.per_target_oracle import PerTargetRetargeter

#: Agreement asked of every published number (positions [m], quaternions, velocities [m/s, rad/s]).
ATOL = 1e-12
#: Configurations covering every branch of the step: the default (bounded, swivel elbows, forearm
#: orientations), the paper's eqs. 1-4, reach mode and the stateful incremental map.
CONFIGS = {
    "default": {},
    "paper": {"mode": "paper", "elbow_placement": "mapped", "orientation_reference": "rest"},
    "reach": {"mode": "reach"},
    "incremental": {"mode": "incremental", "elbow_rotation": True},
    "posture_raw_velocity": {"orientation_reference": "posture", "velocity_tau": 0.0},
}


def assert_same(new, old, where: str) -> None:
    assert (new is None) == (old is None), where
    if new is None:
        return
    assert new.hdr == old.hdr and new.mode == old.mode, where
    assert set(new.upper_arms) == set(old.upper_arms), where
    for t in TARGET_NAMES:
        a, b = new.targets[t], old.targets[t]
        assert (a.valid, a.use_rotation) == (b.valid, b.use_rotation), f"{where} {t}"
        for field in ("p", "q", "v", "w"):
            np.testing.assert_allclose(
                getattr(a, field), getattr(b, field), rtol=0, atol=ATOL, err_msg=f"{where} {t}.{field}"
            )


def compare(config: dict, frames, robot, workspace) -> tuple[int, int]:
    """Feed both retargeters the frames; returns (frames retargeted, targets published invalid)."""
    # The oracle predates the trunk push (tests/retarget/test_trunk.py covers it): both run without it.
    config = {"trunk_clearance": False, **config}
    new = Retargeter(RetargetConfig(**config), workspace=workspace, robot=robot)
    old = PerTargetRetargeter(RetargetConfig(**config), workspace=workspace, robot=robot)
    published = invalid = 0
    for k, f in enumerate(frames):
        out = new.step(f)
        assert_same(out, old.step(f), f"frame {k}")
        if out is not None:
            published += 1
            invalid += sum(not t.valid for t in out.targets.values())
    assert new.counts == old.counts and new.rejects == old.rejects
    return published, invalid


@pytest.mark.parametrize("name", list(CONFIGS))
def test_batched_step_equals_the_per_target_step_on_a_real_clip(name, bvh_clips, robot14, workspace):
    clip = load_clip(bvh_clips[len(bvh_clips) // 2])
    frames = [clip.frame(i, seq=i + 1) for i in range(clip.n_frames)]
    assert compare(CONFIGS[name], frames, robot14, workspace)[0] == clip.n_frames


def test_batched_step_equals_the_per_target_step_on_a_marker_clip_with_gaps(c3d_dir, robot14, workspace):
    """A C3D marker clip: bones go invalid and come back (held poses, velocity restarts)."""
    published = invalid = 0
    for path in sorted(c3d_dir.glob("*.c3d")):
        clip = load_clip(path)
        frames = [clip.frame(i, seq=i + 1) for i in range(clip.n_frames)]
        p, i = compare({}, frames, robot14, workspace)
        published, invalid = published + p, invalid + i
    assert published > 0 and invalid > 0  # the marker sets lose bones (SOURCES.md): the invalid path ran


def test_batched_step_equals_the_per_target_step_through_invalid_bones_and_gaps(robot14, workspace):
    rng = np.random.default_rng(3)
    frames, stamp = [], 0.0
    for k in range(120):
        stamp += 0.9 if k == 60 else 0.01  # one gap past max_gap: velocities restart
        offsets = {b: rng.normal(scale=0.05, size=3) for b in ("left_wrist", "right_wrist", "left_elbow")}
        invalid = ("left_wrist",) if 20 <= k < 25 else ("right_elbow",) if 40 <= k < 42 else ()
        drop = ("right_wrist",) if 80 <= k < 83 else ()
        frames.append(make_frame(k + 1, stamp, offsets=offsets, invalid=invalid, drop=drop))
    for config in CONFIGS.values():
        # with swivel elbows the left elbow is held with its occluded wrist (Retargeter._swivel_occluded): 5 more
        swivel = config.get("elbow_placement", "swivel") == "swivel" and config.get("mode") != "incremental"
        assert compare(config, frames, robot14, workspace) == (len(frames), 5 + 2 + 3 + 5 * swivel)


def test_plain_float_swivel_geometry_equals_the_numpy_one(robot14):
    """elbow.py's placement in plain floats: the numpy formulas' results, the degenerate branches included."""
    from services.retarget.elbow import ArmGeometry, human_swivel
    from tests.retarget.per_target_oracle import human_swivel_numpy, place_numpy, reachable_numpy

    arm = ArmGeometry.measure(robot14, "left")
    rng = np.random.default_rng(5)
    cases = [arm.centre + rng.normal(scale=0.3, size=3) for _ in range(300)]
    cases += [arm.centre.copy(), arm.centre + 1e-12, arm.centre + np.array([0.0, 0.0, 0.9])]  # at the centre, far
    for w in cases:
        np.testing.assert_allclose(arm.reachable(w), reachable_numpy(arm, w), rtol=0, atol=ATOL)
        a = w - arm.centre
        for sw in (rng.normal(size=3), a.copy(), -0.01 * arm.default_swivel, np.zeros(3)):  # along the arm: fallback
            np.testing.assert_allclose(arm.place(w, sw), place_numpy(arm, w, sw), rtol=0, atol=ATOL)
        sh, el = rng.normal(size=3), rng.normal(size=3)
        np.testing.assert_allclose(human_swivel(sh, el, w), human_swivel_numpy(sh, el, w), rtol=0, atol=ATOL)
