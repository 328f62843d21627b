"""MCAP files of bus traffic: round trip, truncated files, replay planning (no bus)."""

from __future__ import annotations

import numpy as np
import pytest

from services.recorder.mcap_io import RecordingWriter, payload_info, read_recording
from services.recorder.replay import ReplayPlan, key_filter, rebase_key
from shared.keys import Keys
from shared.messages import HUMAN_BONES, Bone, Header, HumanFrame, Pose, ServiceStatus


def _frame(seq: int) -> HumanFrame:
    q = np.array([1.0, 0, 0, 0])
    bones = {n: Bone(np.array([seq * 1e-3, 0.0, 1.0]), q) for n in HUMAN_BONES}
    return HumanFrame(Header(seq, seq / 100.0, 1_700_000_000_000_000_000 + seq), "test", Pose(np.zeros(3), q), bones)


def _write(path, n=300, flush_every=50):
    keys = Keys("rec")
    w = RecordingWriter(path, chunk_size=4096)
    sent = []
    for i in range(n):
        key, data = (keys.mocap_frame, _frame(i).encode()) if i % 10 else (keys.status("x"), _status(i))
        w.write(key, data, log_time=10_000_000 * i)
        sent.append((key, data, 10_000_000 * i))
        if i % flush_every == flush_every - 1:
            w.flush()
    return w, sent


def _status(i: int) -> bytes:
    return ServiceStatus("x", "main", "ok", float(i)).encode()


def test_round_trip_keeps_key_payload_and_times(tmp_path):
    w, sent = _write(tmp_path / "a.mcap")
    w.close(summary={"received": str(len(sent))})
    rec = read_recording(tmp_path / "a.mcap")
    got = list(rec)
    assert rec.complete and rec.error == ""
    assert [(r.key, r.data, r.log_time) for r in got] == sent
    assert [r.sequence for r in got] == list(range(len(sent)))
    # publish_time comes from hdr.t0 for messages that carry a header, else the receive time.
    for r in got:
        _, t0 = payload_info(r.data)
        assert r.publish_time == (t0 if t0 is not None else r.log_time)
    assert any(payload_info(r.data)[1] is not None for r in got)
    assert rec.metadata["mimic.recorder"]["received"] == str(len(sent))
    assert {c.topic: c.message_encoding for c in rec.channels.values()} == {
        Keys("rec").mocap_frame: "msgpack",
        Keys("rec").status("x"): "msgpack",
    }


def test_file_cut_anywhere_reads_a_prefix_without_raising(tmp_path):
    """A recording cut at any byte (what SIGKILL leaves) yields a prefix of what was flushed."""
    w, sent = _write(tmp_path / "full.mcap", n=200, flush_every=20)
    w.flush()  # no footer: the state of a killed recorder
    data = (tmp_path / "full.mcap").read_bytes()
    full = list(read_recording(tmp_path / "full.mcap"))
    assert len(full) == len(sent)
    cut = tmp_path / "cut.mcap"
    counts = []
    for end in np.linspace(0, len(data), 60).astype(int):
        cut.write_bytes(data[:end])
        rec = read_recording(cut)
        got = [(r.key, r.data) for r in rec]
        assert got == [(k, d) for k, d, _ in sent[: len(got)]]
        assert not rec.complete
        counts.append(len(got))
    assert counts == sorted(counts) and counts[-1] == len(sent)
    assert 0 < counts[len(counts) // 2] < len(sent)


def test_garbage_file_is_an_error_not_a_crash(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(ValueError, match="not an MCAP"):
        read_recording(bad)
    # A valid magic followed by garbage reads as an empty, errored recording.
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\xff" * 40)
    rec = read_recording(bad)
    assert list(rec) == [] and rec.error
    with pytest.raises(FileNotFoundError):
        read_recording(tmp_path / "missing.mcap")


def test_rebase_key_and_filter():
    a, b = Keys("a"), Keys("b-2")
    assert rebase_key(a.mocap_frame, "b-2") == b.mocap_frame
    assert rebase_key(a.command("hqp"), "b-2") == b.command("hqp")
    with pytest.raises(ValueError):
        rebase_key("other/a/mocap/frame", "b")
    with pytest.raises(ValueError):
        rebase_key(a.mocap_frame, "bad/session")
    f = key_filter("mocap/frame")
    assert f.includes(a.mocap_frame) and not f.includes(a.targets)
    assert key_filter(None) is None


def test_plan_timing_filter_and_session():
    class R:
        def __init__(self, key, t):
            self.key, self.data, self.log_time = key, b"x", t

    k = Keys("a")
    records = [R(k.status("s"), 0), R(k.mocap_frame, 1_000_000_000), R(k.targets, 1_500_000_000)]
    records.append(R(k.mocap_frame, 3_000_000_000))
    due = list(ReplayPlan(speed=2.0, only="mocap/frame", session="z").plan(records))
    assert [d.key for d in due] == [Keys("z").mocap_frame] * 2
    assert [d.offset for d in due] == pytest.approx([0.0, 1.0])  # (3 s - 1 s) / speed 2
    fast = list(ReplayPlan(speed=None).plan(records))
    assert [d.offset for d in fast] == [0.0] * 4 and [d.key for d in fast] == [r.key for r in records]
    with pytest.raises(ValueError):
        ReplayPlan(speed=0)
