"""The one scorer (robot states against targets, keyed by ``hdr.t0``) and the one sequence guard."""

from __future__ import annotations

import numpy as np
import pytest

from services.ingest.sanitizer import FrameSanitizer
from services.launcher.monitor import STARTUP_S, StackMonitor
from shared.messages import Header, Pose, RobotState, Target, TaskTargets
from shared.scoring import TargetScorer
from shared.sequence import SequenceGuard

IDENT = np.array([1.0, 0.0, 0.0, 0.0])


def targets(seq: int, t0: int, x: float) -> TaskTargets:
    z = np.zeros(3)
    return TaskTargets(
        Header(seq, seq * 0.01, t0), {"left_wrist": Target(np.array([x, 0, 0]), IDENT, z, z, True, False)}
    )


def state(seq: int, t0: int, x: float) -> RobotState:
    frames = {"left_wrist": Pose(np.array([x, 0.0, 0.0]), IDENT)}
    return RobotState(Header(seq, seq * 0.01, t0), [], np.zeros(0), np.zeros(0), frames, 0.0)


def test_scorer_keys_frames_by_t0_across_a_clip_restart():
    sc = TargetScorer()
    sc.add_targets(targets(0, 100, 0.0))  # first clip, seq 0
    sc.add_targets(targets(0, 200, 1.0))  # second clip starts seq again at 0, 1 m away
    assert sc.add_state(state(0, 100, 0.10)) == (True, None)
    assert sc.add_state(state(0, 100, 0.02)) == (False, None)  # same frame: its last state counts
    new, err = sc.add_state(state(0, 200, 0.97))
    assert new and err == pytest.approx({"left_wrist": 0.02})  # first clip's frame, its last state
    # Keyed by seq the second clip's seq 0 would be scored against the first clip's targets (0.97 m).
    assert sc.flush() == pytest.approx({"left_wrist": 0.03})
    assert sc.add_state(state(0, 150, 0.0)) == (False, None)  # an older frame: ignored


def test_monitor_uses_the_scorer():
    mon = StackMonitor()
    mon.on_targets(targets(0, 100, 0.0))
    mon.on_targets(targets(0, 200, 1.0))
    mon.on_state(state(0, 100, 0.05), now_ns=100 + 2_000_000)
    mon.on_state(state(0, 200, 0.99), now_ns=200 + 3_000_000)
    s = mon.summary()
    assert s["wrist_err_cm"]["mean"] == pytest.approx(3.0)  # (5 + 1) / 2 cm
    assert s["latency_ms"]["samples"] == 2 and s["latency_ms"]["max"] == pytest.approx(3.0)


def test_monitor_summarises_start_up_apart_from_the_steady_state():
    """Two clips (the stamp goes back at the second) and a source back after a silence: the robot is
    20 cm off for the first 0.5 s of each stream, 1 cm off after; the steady figures are 1 cm."""
    mon = StackMonitor()
    t0, ns = 10**12, 1_000_000_000
    seq = 0
    # 60 Hz; the second clip's stamp starts again from 0; the third stream's stamp goes on, but
    # after a silence of 2.5 s (the robot held its pose meanwhile).
    for stream_start, stamp0, n in ((0.0, 0.0, 180), (3.5, 0.0, 180), (9.0, 10.0, 120)):
        for i in range(n):
            t = t0 + int((stream_start + i / 60) * ns)
            off = 0.20 if i / 60 < 0.5 else 0.01
            mon.on_targets(TaskTargets(Header(i, stamp0 + i / 60, t), targets(i, t, 0.0).targets))
            mon.on_state(state(i, t, off), now_ns=t + 5_000_000)
            seq += 1
    s = mon.summary()
    w = s["wrist_err_cm"]
    assert s["error_split"]["streams"] == 3 and s["error_split"]["startup_s"] == STARTUP_S == 1.0
    assert w["max"] == pytest.approx(20.0) and w["samples"] == seq
    assert w["steady"]["max"] == pytest.approx(1.0) and w["steady"]["mean"] == pytest.approx(1.0)
    assert w["startup"]["max"] == pytest.approx(20.0)
    assert w["startup"]["samples"] == 3 * 60 and w["steady"]["samples"] == seq - 3 * 60
    assert "first 1 s of each stream" in s["error_split"]["rule"]


def test_sequence_guard_rule():
    g = SequenceGuard(reset_gap=100, resync_after=3)
    first = Header(500, 5.0, 1)
    assert g.check(first).ok
    g.accept(first)
    assert g.check(Header(500, 5.1, 1)).reason == "duplicate_seq"
    assert g.check(Header(499, 5.2, 1)).reason == "seq_backwards"
    v = g.check(Header(501, 5.0, 1))  # third bad in a row: a restart
    assert v.ok and v.restarted
    g.accept(Header(501, 5.0, 1))
    assert g.check(Header(502, 4.9, 1)).reason == "time_backwards"
    assert g.check(Header(503, 5.1, 1)).ok  # in order again: the count of bad ones starts over
    assert g.check(Header(0, 0.0, 1)).restarted  # more than reset_gap back: a restart at once
    # Per source: another source's history does not judge this one.
    assert g.check(Header(1, 0.0, 1), source="other").ok
    with pytest.raises(ValueError, match="must be >= 1"):
        SequenceGuard(resync_after=0)


def test_sequence_guard_sees_a_restarted_source_at_once():
    """A sender run again (seq from 0, a later t0) is followed from its first frame; a duplicated or
    late packet of the old run (its own, earlier t0) is still rejected."""
    g = SequenceGuard()
    for i in range(600):
        g.accept(Header(i, i / 60, 1_000 + i))
    assert g.check(Header(599, 9.98, 1_599)).reason == "duplicate_seq"  # same packet twice
    assert g.check(Header(300, 5.0, 1_300)).reason == "seq_backwards"  # a late packet
    v = g.check(Header(0, 0.0, 5_000))  # the sender restarted: seq 0, made after the last frame
    assert v.ok and v.restarted, v
    # Without trusting t0 (stamped on arrival) the same frame waits for the resync rule.
    g2 = SequenceGuard(trust_t0=False)
    g2.accept(Header(599, 9.98, 1_599))
    assert g2.check(Header(0, 0.0, 5_000)).reason == "seq_backwards"


def test_sanitizer_follows_the_guard_rule():
    from shared.messages import Bone, HumanFrame

    def frame(seq: int, stamp: float) -> HumanFrame:
        return HumanFrame(Header(seq, stamp, 1), "s", Pose(np.zeros(3), IDENT), {"pelvis": Bone(np.zeros(3), IDENT)})

    s = FrameSanitizer(resync_after=2)
    assert s.step(frame(10, 1.0))[0] is not None
    out, issues = s.step(frame(11, 0.5))
    assert out is None and issues[0].reason == "time_backwards"
    out, issues = s.step(frame(9, 1.2))  # second bad frame in a row: the source restarted
    assert out is not None and issues[0].reason == "seq_reset"
