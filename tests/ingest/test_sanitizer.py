"""FrameSanitizer and the lenient decoder: repairs and drops, without the bus."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from services.ingest.live import LiveIngest
from services.ingest.sanitizer import FrameSanitizer, decode_lenient
from shared.messages import Bone, Header, HumanFrame, MessageError, Pose

Q1 = np.array([1.0, 0.0, 0.0, 0.0])


def frame(seq, bones=None, root_p=(0.0, 0.0, 1.0), root_q=Q1, stamp=None):
    bones = bones or {
        "pelvis": Bone(np.zeros(3), Q1.copy()),
        "left_wrist": Bone(np.array([0.3, 0.2, 0.1]), Q1.copy()),
        "right_wrist": Bone(np.array([0.3, -0.2, 0.1]), Q1.copy()),
    }
    return HumanFrame(
        Header(seq, seq / 30 if stamp is None else stamp, 1), "test", Pose(np.array(root_p), np.array(root_q)), bones
    )


def reasons(issues):
    return [(i.reason, i.action) for i in issues]


def test_clean_frames_pass_unchanged():
    s = FrameSanitizer()
    for k in range(3):
        out, issues = s.step(frame(k))
        assert out is not None and not issues
        assert out.hdr.seq == k


def test_duplicate_and_out_of_order_seq_dropped():
    s = FrameSanitizer()
    s.step(frame(10))
    out, issues = s.step(frame(10))
    assert out is None and reasons(issues) == [("duplicate_seq", "dropped")]
    out, issues = s.step(frame(7))
    assert out is None and reasons(issues) == [("seq_backwards", "dropped")]
    out, _ = s.step(frame(5000))  # gaps are fine (lost datagrams)
    assert out is not None
    out, issues = s.step(frame(0))  # far back: the source restarted
    assert out is not None and reasons(issues) == [("seq_reset", "repaired")]
    assert s.counts[("duplicate_seq", "dropped")] == 1


def test_nan_bone_invalidated_with_last_good_position():
    s = FrameSanitizer()
    s.step(frame(0))
    f = frame(1)
    f.bones["left_wrist"].p = np.array([np.nan, 0.0, 0.0])
    out, issues = s.step(f)
    assert ("nan_bone", "invalidated") in reasons(issues)
    b = out.bones["left_wrist"]
    assert b.valid is False and np.allclose(b.p, [0.3, 0.2, 0.1])
    HumanFrame.decode(out.encode())  # what we publish is always a valid message


def test_nan_bone_without_history_is_removed():
    f = frame(0)
    f.bones["left_wrist"].p = np.array([np.inf, 0.0, 0.0])
    out, issues = FrameSanitizer().step(f)
    assert "left_wrist" not in out.bones and ("nan_bone", "invalidated") in reasons(issues)


def test_quaternions_repaired_or_rejected():
    s = FrameSanitizer()
    f = frame(0)
    f.bones["left_wrist"].q = np.array([1.02, 0.0, 0.0, 0.0])
    out, issues = s.step(f)
    assert ("quat_normalised", "repaired") in reasons(issues)
    assert np.isclose(np.linalg.norm(out.bones["left_wrist"].q), 1.0) and out.bones["left_wrist"].valid
    f = frame(1)
    f.bones["right_wrist"].q = np.zeros(4)
    out, issues = s.step(f)
    assert ("bad_quaternion", "invalidated") in reasons(issues) and out.bones["right_wrist"].valid is False
    out, issues = s.step(frame(2, root_q=(0.5, 0.0, 0.0, 0.0)))
    assert out is None and ("bad_root_quaternion", "dropped") in reasons(issues)
    out, issues = s.step(frame(3, root_q=(0.0, 0.0, 0.0, 0.97)))
    assert out is not None and np.allclose(out.root.q, [0, 0, 0, 1])


def test_nan_root_and_stamp_dropped():
    s = FrameSanitizer()
    out, issues = s.step(frame(0, root_p=(np.nan, 0, 0)))
    assert out is None and reasons(issues) == [("nan_root", "dropped")]
    out, issues = s.step(frame(1, stamp=float("nan")))
    assert out is None


def test_missing_bones_reported_and_empty_dropped():
    s = FrameSanitizer()
    s.step(frame(0))
    out, issues = s.step(frame(1, bones={"pelvis": Bone(np.zeros(3), Q1.copy())}))
    assert ("missing_bone", "invalidated") in reasons(issues)
    assert set(out.bones) == {"pelvis"}
    out, issues = s.step(frame(2, bones={"left_wrist": Bone(np.zeros(3), Q1.copy(), False)}))
    assert out is None and ("empty", "dropped") in reasons(issues)


def test_out_of_range_bone():
    f = frame(0)
    f.bones["left_wrist"].p = np.array([40.0, 0.0, 0.0])  # centimetres sent as metres
    out, issues = FrameSanitizer().step(f)
    assert ("bone_out_of_range", "invalidated") in reasons(issues) and "left_wrist" not in out.bones


def _raw(**over):
    d = {"v": 1, "t": "HumanFrame", "hdr": [5, 0.1, 7], "src": "x", "root": [[0, 0, 1], [1, 0, 0, 0]],
         "names": ["pelvis", "left_wrist"], "p": [[0, 0, 0], [0.3, 0.2, 0.1]], "q": [[1, 0, 0, 0], [1, 0, 0, 0]],
         "valid": [True, True]}  # fmt: skip
    d.update(over)
    return msgpack.packb(d)


def test_decode_lenient_keeps_nan_and_reports_unknown_bones():
    f, issues = decode_lenient(_raw(p=[[0, 0, 0], [float("nan"), 0, 0]]))
    assert np.isnan(f.bones["left_wrist"].p[0])
    with pytest.raises(MessageError):
        HumanFrame.decode(_raw(p=[[0, 0, 0], [float("nan"), 0, 0]]))  # the strict decoder would refuse
    f, issues = decode_lenient(_raw(names=["pelvis", "left_toe"]))
    assert set(f.bones) == {"pelvis"} and issues[0].reason == "unknown_bone"
    for bad, reason in ((b"\xc1garbage", "msgpack"), (_raw(v=9), "version"), (_raw(hdr=[1, 2]), "missing")):
        with pytest.raises(MessageError) as exc:
            decode_lenient(bad)
        assert exc.value.reason == reason


def test_live_ingest_udp_path():
    core = LiveIngest()
    out, issues = core.step("udp", frame(3).encode(), now_ns=99)
    assert out is not None and out.hdr.t0 == 1 and not issues  # the sender's t0 is kept
    out, issues = core.step("udp", frame(3).encode(), now_ns=99)
    assert out is None and issues[0].reason == "duplicate_seq"
    out, issues = core.step("udp", b"junk", now_ns=99)
    assert out is None and issues[0].action == "dropped"
    core = LiveIngest(restamp=True)
    out, _ = core.step("udp", frame(3).encode(), now_ns=99)
    assert out.hdr.t0 == 99
