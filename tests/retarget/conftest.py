"""Synthetic HumanFrames and a shared retargeting setup for the retarget tests."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shared.messages import Bone, Header, HumanFrame, Pose

IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])

#: Operator at rest (arms hanging), pelvis frame x forward, y left, z up [m]; y of the right side is mirrored.
REST_LEFT = {
    "left_shoulder": (0.0, 0.18, 0.45),
    "left_elbow": (0.0, 0.20, 0.17),
    "left_wrist": (0.02, 0.20, -0.08),
    "left_hand": (0.03, 0.20, -0.16),
}


def make_frame(
    seq: int,
    stamp: float,
    offsets: dict[str, np.ndarray] | None = None,
    quats: dict[str, np.ndarray] | None = None,
    invalid: tuple[str, ...] = (),
    drop: tuple[str, ...] = (),
    t0: int = 123456789,
) -> HumanFrame:
    """Synthetic operator frame: the rest pose plus per-bone position offsets (3,) [m]."""
    bones = {}
    for name, p in REST_LEFT.items():
        for side, sign in (("left", 1.0), ("right", -1.0)):
            bone = name.replace("left", side)
            pos = np.array([p[0], sign * p[1], p[2]])
            if offsets and bone in offsets:
                pos = pos + offsets[bone]
            q = quats[bone] if quats and bone in quats else IDENTITY_Q
            if bone not in drop:
                bones[bone] = Bone(pos, np.asarray(q, dtype=float), bone not in invalid)
    return HumanFrame(Header(seq, stamp, t0), "synthetic", Pose(np.zeros(3), IDENTITY_Q.copy()), bones)


def random_quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


@pytest.fixture(scope="session")
def workspace(robot14, tmp_path_factory):
    """Default workspace (12 000 samples, 5-95 % box), cached in a test-private folder."""
    import os

    from services.retarget.workspace import load_workspace

    old = os.environ.get("MIMIC_CACHE_DIR")
    os.environ["MIMIC_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    try:
        return load_workspace(robot14.profile, robot=robot14, progress=False)
    finally:
        if old is None:
            os.environ.pop("MIMIC_CACHE_DIR", None)
        else:
            os.environ["MIMIC_CACHE_DIR"] = old


def targets_without_and_with(bvh_clips, name: str, workspace, robot14, option: str) -> dict[bool, list]:
    """The published targets of the real clip whose name contains ``name``, retargeted with the boolean
    ``RetargetConfig`` field ``option`` off (False) and on (True)."""
    from services.evaluation.runner import clip_targets
    from services.ingest import load_clip
    from services.retarget.retargeter import RetargetConfig, Retargeter

    clip = load_clip(next(p for p in bvh_clips if name in p.name))
    return {
        on: clip_targets(clip, Retargeter(RetargetConfig(**{option: on}), workspace=workspace, robot=robot14))
        for on in (False, True)
    }


def torso_front(trunk, R: np.ndarray, depth: float, elbow: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A left wrist target (3,) [m] straight in front of the torso's axis at belly height, whose hand lies
    ``depth`` [m] inside the torso's front (negative: outside), and the torso's outward normal there (3,).
    ``elbow`` (3,): the elbow target, whose forearm poses a hand chain (``TrunkClearance.nearest``)."""

    def nearest(p):
        return trunk.nearest("left", p, R, None if elbow is None else p - elbow)

    g = trunk.model.geom("polytope:torso_link").id
    _, axis, _, _ = trunk._axes[g]
    mujoco.mj_kinematics(trunk.model, trunk.data)
    centre = trunk.data.geom_xpos[g]  # the torso link's own middle (the axis runs on up through the chest and head)
    normal = np.array([1.0, 0.0, 0.0]) - axis[0] * axis
    normal /= np.linalg.norm(normal)
    far = centre + 0.4 * normal  # hand clear of everything
    d_far = nearest(far)[0]
    assert d_far > trunk.clearance  # (the lookout caps it; walk in until it is measured)
    p = far.copy()
    for _ in range(50):
        d, _, _ = nearest(p)
        if d < trunk.clearance:
            break
        p = p - 0.01 * normal
    # the torso's front is flat there: the distance falls 1:1 along the normal
    return p - normal * (d + depth), normal
