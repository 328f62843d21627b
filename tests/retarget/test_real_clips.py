"""Retargeting the real BVH clips (Bandai Namco dataset, read from ../shared/data/mocap/bvh)."""

from __future__ import annotations

import numpy as np
import pytest

from services.ingest.clip import load_clip
from services.retarget.calibration import from_recording
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.rotations import quat_to_matrix
from shared.targets import TARGET_NAMES, elbow_of, wrist_of

#: Seed 000's eqs. (1)-(4) as written (the product defaults are swivel elbows and forearm orientations).
PAPER = {"elbow_placement": "mapped", "orientation_reference": "rest"}


@pytest.fixture(scope="module")
def clips(bvh_clips):
    return {p.stem: load_clip(p) for p in bvh_clips}


def frames_of(clip):
    return [clip.frame(i, seq=i + 1) for i in range(clip.n_frames)]


def run(retargeter, frames):
    outs = [retargeter.step(f) for f in frames]
    assert all(o is not None for o in outs), retargeter.rejects
    return outs


def test_every_clip_in_the_box_bounded_mode_auto_calibrated(clips, robot14, workspace, mocap_sources):
    """Bounded mode, calibrated from the clip's first frame (arms hanging), eqs. (1)-(3) for every target."""
    assert sorted(f"{name}.bvh" for name in clips) == sorted(mocap_sources.bvh_names())
    n_checked = 0
    for name, clip in clips.items():
        r = Retargeter(RetargetConfig(mode="bounded", **PAPER), workspace=workspace, robot=robot14)
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
        paper = Retargeter(RetargetConfig(mode="paper", **PAPER), calibration=cal, workspace=workspace, robot=robot14)
        bounded = Retargeter(
            RetargetConfig(mode="bounded", **PAPER), calibration=cal, workspace=workspace, robot=robot14
        )
        for a, b in zip(run(paper, frames), run(bounded, frames)):
            for t in TARGET_NAMES:
                assert workspace.contains(t, a.targets[t].p, tol=1e-9), f"{name} {t}"
                np.testing.assert_allclose(a.targets[t].p, b.targets[t].p, atol=1e-12)
        assert not any(k.startswith("clamped") for k in bounded.counts), (name, bounded.counts)


def test_first_frame_rest_gives_robot_rest_orientation_on_real_clips(clips, robot14, workspace):
    rest = robot14.frame_poses(robot14.q_rest, names=TARGET_NAMES)
    for clip in clips.values():
        r = Retargeter(RetargetConfig(**PAPER), workspace=workspace, robot=robot14)
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


def test_default_elbow_targets_sit_at_the_robot_arm_lengths_on_real_clips(clips, robot14, workspace):
    """Swivel elbows (the default, here with the box mapping): every valid elbow target is at the robot's
    upper-arm length from its shoulder centre and its forearm length from the wrist target, so both are
    reachable, unless bounded mode pulled it onto the workspace box; the wrist stays within the arm's
    reach. (The default "reach" mapping publishes no box clamp at all: test_reach.py.)"""
    on_sphere = 0
    for name, clip in clips.items():
        r = Retargeter(RetargetConfig(mode="bounded"), workspace=workspace, robot=robot14)
        for out in run(r, frames_of(clip)):
            for side, arm in r.arms.items():
                t = elbow_of(side)
                w, e = out.targets[wrist_of(side)], out.targets[t]
                if not (w.valid and e.valid):
                    continue
                assert workspace.contains(t, e.p, tol=1e-9), (name, t)
                assert arm.reach[0] - 1e-9 <= np.linalg.norm(w.p - arm.centre) <= arm.reach[1] + 1e-9, (name, side)
                on_box = np.any(np.isclose(e.p, workspace.lower[t]) | np.isclose(e.p, workspace.upper[t]))
                lengths_ok = abs(np.linalg.norm(e.p - arm.centre) - arm.upper) < 1e-6
                lengths_ok &= abs(np.linalg.norm(w.p - e.p) - arm.fore) < 1e-6
                assert lengths_ok or on_box, (name, t, out.hdr.seq)
                on_sphere += lengths_ok
    assert on_sphere > 2 * 1000
