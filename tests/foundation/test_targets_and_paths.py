"""Target names and sides (shared.targets) and the repo's one outside path (shared.paths)."""

from __future__ import annotations

import pytest

from shared import paths
from shared.messages import HUMAN_BONES
from shared.targets import ELBOWS, SIDES, TARGET_NAMES, WRISTS, elbow_of, side_of, wrist_of


def test_every_target_has_one_side_and_its_arm_partners():
    assert set(TARGET_NAMES) == set(WRISTS) | set(ELBOWS) and len(set(TARGET_NAMES)) == len(TARGET_NAMES)
    for side, w, e in zip(SIDES, WRISTS, ELBOWS, strict=True):
        assert side_of(w) == side_of(e) == side
        assert wrist_of(e) == wrist_of(w) == wrist_of(side) == w
        assert elbow_of(w) == elbow_of(side) == e
    # the targets are driven by the human bones of the same name by default
    assert set(TARGET_NAMES) <= set(HUMAN_BONES)


@pytest.mark.parametrize("bad", ["left", "left_hand", "pelvis", "", "LEFT_WRIST"])
def test_side_of_refuses_non_targets(bad):
    with pytest.raises(KeyError, match="unknown target"):
        side_of(bad)


def test_mocap_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(paths.MOCAP_DIR_ENV, str(tmp_path))
    assert paths.mocap_dir() == tmp_path
    monkeypatch.delenv(paths.MOCAP_DIR_ENV)
    assert paths.mocap_dir() == (paths.REPO_ROOT / ".." / "shared" / "data" / "mocap").resolve()
    assert (paths.REPO_ROOT / "shared" / "paths.py").is_file() and paths.MODELS_DIR.is_dir()
