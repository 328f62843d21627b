"""Hands-only HumanFrames (VR controllers) through the UDP ingest path and the bus codec."""

from __future__ import annotations

import numpy as np

from services.ingest import load_clip
from services.ingest.live import LiveIngest
from shared.messages import HumanFrame
from shared.wrist_only import HAND_BONES, is_wrist_only, wrists_only


def test_hands_only_frames_pass_udp_ingest_and_the_bus_codec(bvh_clips):
    clip = load_clip(bvh_clips[0])
    live = LiveIngest()
    for i in range(5):
        frame = wrists_only(clip.frame(i, seq=i + 1))
        assert set(frame.bones) <= set(HAND_BONES) and {"left_wrist", "right_wrist"} <= set(frame.bones)
        assert is_wrist_only(frame) and not is_wrist_only(clip.frame(i, seq=i + 1))
        out, issues = live.step("udp", frame.encode(), 1_000_000 + i)
        assert out is not None, issues
        assert not [x for x in issues if x.action != "repaired"]  # nothing dropped or invalidated
        back = HumanFrame.decode(out.encode())
        assert set(back.bones) == set(frame.bones)
        np.testing.assert_allclose(back.bones["left_wrist"].p, frame.bones["left_wrist"].p)
