"""The recorder tells bus losses apart from its own: seq gaps of mocap frames."""

from __future__ import annotations

import numpy as np

from services.recorder.gaps import SeqGaps
from shared.keys import Keys
from shared.messages import Bone, Header, HumanFrame, Pose, ServiceStatus

Q = np.array([1.0, 0, 0, 0])


def _frame(seq: int, src: str = "a") -> bytes:
    return HumanFrame(
        Header(seq, seq / 60, 1), src, Pose(np.zeros(3), Q), {"right_wrist": Bone(np.zeros(3), Q)}
    ).encode()


def test_seq_gaps_count_lost_frames_per_source_not_restarts():
    k = Keys("s")
    g = SeqGaps()
    for seq in (0, 1, 2, 5, 6, 9):  # 3, 4, 7, 8 lost
        g.step(k.mocap_frame, _frame(seq))
    for seq in (0, 1, 2):  # another source interleaved: its own numbering, nothing lost
        g.step(k.mocap_frame, _frame(seq, "b"))
    g.step(k.mocap_frame, _frame(0))  # source "a" restarted: not a loss
    g.step(k.mocap_frame, _frame(1))
    g.step(k.status("retarget"), ServiceStatus("retarget", "main", "ok", 1.0).encode())  # not a frame stream
    g.step(k.mocap_frame, b"\xc1garbage")
    assert g.missing == 4 and g.restarts == 1
