"""The by-clip split of ``mimic posture train``: its folds hold every clip out exactly once (numpy only)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from services.posture.cli import split_clips

NAMES = [f"/data/clip_{c}.bvh" for c in "qwertyuiopasdfghjklzxcv"]  # 23, unsorted on purpose
#: ``mimic posture train`` on four of them; the runs below stop at a check before any work
TRAIN = [sys.executable, "-m", "services.cli", "posture", "train", *NAMES[:4], "--out", "x.npz", "--json", "x.json"]


def test_the_folds_partition_the_clips_and_the_default_fold_is_every_kth():
    folds = [split_clips(NAMES, 4, f) for f in range(4)]
    held = [test for _train, test in folds]
    assert sorted(p for test in held for p in test) == sorted(NAMES)  # each clip held out once
    assert [len(t) for t in held] == [6, 6, 6, 5]
    for train, test in folds:
        assert not set(train) & set(test) and len(train) + len(test) == len(NAMES)
    ordered = sorted(NAMES)
    assert split_clips(NAMES, 4) == folds[3]
    assert folds[3][1] == ordered[3::4]  # every 4th clip by name, 1-based: the split of the earlier sessions
    assert folds[0][1] == ordered[0::4]


def test_a_fold_outside_the_range_is_a_one_line_error():
    with pytest.raises(ValueError, match=r"--holdout-fold must be in 0\.\.3"):
        split_clips(NAMES, 4, 4)
    cmd = TRAIN
    r = subprocess.run(
        [*cmd, "--holdout-fold", "-1"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode != 0
    assert r.stderr.strip().splitlines()[-1] == "--holdout-fold must be in 0..3 for --holdout-every 4, got -1"


def test_the_augmentation_default_is_the_elbow_kinds_only():
    """``--augment-deg`` defaults to the elbow kind's turns; a kind that cannot turn its labels gets none and is
    not refused (this run stops at the fold check, which comes after the augmentation check)."""
    cmd = TRAIN
    for kind in ("posture", "swivel", "velocity"):
        r = subprocess.run([*cmd, "--action-kind", kind, "--holdout-fold", "7"], capture_output=True, text=True,
                           timeout=120)  # fmt: skip
        assert r.returncode != 0 and r.stderr.strip().splitlines()[-1].startswith("--holdout-fold must be"), r.stderr
    r = subprocess.run([*cmd, "--action-kind", "posture", "--augment-deg", "15", "--holdout-fold", "7"],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode != 0 and "--action-kind elbow" in r.stderr
