"""A source without measured orientations (markers only, e.g. C3D): its wrists are published without a rotation
to track, so the solver never chases the placeholder (identity) hand orientation."""

from __future__ import annotations

import msgpack
import numpy as np

from services.evaluation.runner import clip_targets
from services.ingest.clip import load_clip
from services.ingest.sanitizer import decode_lenient
from services.retarget.retargeter import RetargetConfig, Retargeter
from shared.messages import Bone, Header, HumanFrame, Pose
from shared.targets import WRISTS


def test_marker_clip_wrists_carry_no_rotation_and_a_bvh_clip_does(robot14, c3d_dir, bvh_clips):
    for path, oriented in ((c3d_dir / "ezc3d-testFiles_Qualisys.c3d", False), (bvh_clips[0], True)):
        clip = load_clip(path)
        assert clip.frame(0, seq=0).oriented is oriented
        targets = clip_targets(clip, Retargeter(RetargetConfig(), robot=robot14))
        assert targets
        assert {tt.targets[w].use_rotation for tt in targets for w in WRISTS} == {oriented}, path.name


def test_the_lenient_decoder_keeps_the_flag_and_repairs_a_bad_one():
    q = np.array([1.0, 0.0, 0.0, 0.0])
    frame = HumanFrame(Header(3, 0.1, 7), "udp", Pose(np.zeros(3), q), {"left_wrist": Bone(np.ones(3), q)}, False)
    decoded, issues = decode_lenient(frame.encode())
    assert decoded.oriented is False and not issues
    d = msgpack.unpackb(frame.encode())
    d["ori"] = "no"
    decoded, issues = decode_lenient(msgpack.packb(d))
    assert decoded.oriented is True
    assert [(i.reason, i.action) for i in issues] == [("malformed_ori", "repaired")]
