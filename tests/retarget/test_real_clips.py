"""Retargeting the real BVH clips (Bandai Namco dataset, read from ../shared/data/mocap/bvh)."""

from __future__ import annotations

import numpy as np
import pytest

from services.retarget.calibration import from_recording
from services.retarget.orientation import quat_to_matrix
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.messages import TARGET_NAMES

clip_mod = pytest.importorskip("services.ingest.clip", reason="ingest service (services/ingest/clip.py) not available")


@pytest.fixture(scope="module")
def clips(bvh_clips):
    return {p.stem: clip_mod.load_clip(p) for p in bvh_clips}


def frames_of(clip):
    return [clip.frame(i, seq=i + 1) for i in range(clip.n_frames)]


def run(retargeter, frames):
    outs = [retargeter.step(f) for f in frames]
    assert all(o is not None for o in outs), retargeter.rejects
    return outs


def test_every_clip_in_the_box_bounded_mode_auto_calibrated(clips, robot14, workspace):
    """The service's default path: bounded mode, calibrated from the clip's first frame (arms hanging)."""
    assert len(clips) >= 10
    n_checked = 0
    for name, clip in clips.items():
        r = Retargeter(RetargetConfig(mode="bounded"), workspace=workspace, robot=robot14)
        for out in run(r, frames_of(clip)):
            for t in TARGET_NAMES:
                tgt = out.targets[t]
                assert np.all(np.isfinite(tgt.p)) and np.all(np.isfinite(tgt.v))
                assert workspace.contains(t, tgt.p), f"{name} seq {out.hdr.seq} {t} {tgt.p} outside the box"
                n_checked += tgt.valid
    assert n_checked > 4 * 1000


def test_every_clip_maps_inside_without_clamping_when_calibrated_from_the_clip(clips, robot14, workspace):
    """Calibrated on the clip itself, eqs. (1)-(3) land inside the box on their own: clamping never acts,
    and paper and bounded modes agree (eq. (1) makes eq. (3)'s scale fit both sides)."""
    for name, clip in clips.items():
        frames = frames_of(clip)
        cal = from_recording(frames, name=name)
        paper = Retargeter(RetargetConfig(mode="paper"), calibration=cal, workspace=workspace, robot=robot14)
        bounded = Retargeter(RetargetConfig(mode="bounded"), calibration=cal, workspace=workspace, robot=robot14)
        for a, b in zip(run(paper, frames), run(bounded, frames)):
            for t in TARGET_NAMES:
                assert workspace.contains(t, a.targets[t].p, tol=1e-9), f"{name} {t}"
                np.testing.assert_allclose(a.targets[t].p, b.targets[t].p, atol=1e-12)
        assert not any(k.startswith("clamped") for k in bounded.counts), (name, bounded.counts)


def test_first_frame_rest_gives_robot_rest_orientation_on_real_clips(clips, robot14, workspace):
    rest = robot14.frame_poses(robot14.q_rest, names=TARGET_NAMES)
    for clip in clips.values():
        r = Retargeter(RetargetConfig(), workspace=workspace, robot=robot14)
        out = r.step(clip.frame(0, seq=1))
        for t in TARGET_NAMES:
            np.testing.assert_allclose(quat_to_matrix(out.targets[t].q), rest[t][1], atol=1e-9)


def test_velocities_are_consistent_with_positions_on_a_real_clip(clips, robot14, workspace):
    clip = clips[sorted(clips)[-1]]
    r = Retargeter(RetargetConfig(velocity_tau=0.0), workspace=workspace, robot=robot14)
    outs = run(r, frames_of(clip))
    p = np.array([o.targets["right_wrist"].p for o in outs])
    v = np.array([o.targets["right_wrist"].v for o in outs])
    dt = np.diff(clip.times)[:, None]
    np.testing.assert_allclose(v[1:], np.diff(p, axis=0) / dt, atol=1e-9)
    assert np.abs(v).max() < 10.0  # m/s: a waving hand, not a glitch
    r = Retargeter(RetargetConfig(velocity_tau=0.05), workspace=workspace, robot=robot14)
    vf = np.array([o.targets["right_wrist"].v for o in run(r, frames_of(clip))])
    assert np.linalg.norm(np.diff(vf, axis=0), axis=1).mean() < np.linalg.norm(np.diff(v, axis=0), axis=1).mean()
