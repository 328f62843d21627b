"""Message contracts: round trips, and every malformed payload gives one typed error."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.messages import (
    HUMAN_BONES,
    SCHEMA_VERSION,
    Bone,
    Header,
    HumanFrame,
    JointCommand,
    MessageError,
    Pose,
    RobotState,
    ServiceStatus,
    Target,
    TaskTargets,
    peek_type,
)

Q_ID = np.array([1.0, 0.0, 0.0, 0.0])


def _quat(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def make_frame(rng=None, seq=7) -> HumanFrame:
    rng = rng or np.random.default_rng(0)
    bones = {n: Bone(rng.normal(size=3), _quat(rng), bool(i % 3)) for i, n in enumerate(HUMAN_BONES)}
    return HumanFrame(Header(seq, 1.25), "test", Pose(rng.normal(size=3), _quat(rng)), bones)


def make_targets(seq=7) -> TaskTargets:
    t = {
        n: Target(np.ones(3) * i, Q_ID, np.zeros(3), np.zeros(3), True, "wrist" in n)
        for i, n in enumerate(("left_wrist", "right_wrist", "left_elbow", "right_elbow"))
    }
    return TaskTargets(Header(seq, 0.5), t, "bounded")


def make_command() -> JointCommand:
    return JointCommand(
        Header(3, 0.1),
        "main",
        "hqp-nullspace",
        ["a", "b"],
        np.array([0.1, -0.2]),
        np.array([1.0, 2.0]),
        [1e-4, 2e-3],
        0.12,
        "ok",
        5,
        1,
        "",
        12.5,
    )


def make_state() -> RobotState:
    return RobotState(
        Header(3, 0.1), ["a", "b"], np.zeros(2), np.ones(2), {"left_wrist": Pose(np.ones(3), Q_ID)}, 1.5, "main", False
    )


def test_round_trips_preserve_every_field():
    f = make_frame()
    g = HumanFrame.decode(f.encode())
    assert g.hdr == f.hdr and g.source == f.source
    for n in HUMAN_BONES:
        np.testing.assert_allclose(g.bones[n].p, f.bones[n].p)
        np.testing.assert_allclose(g.bones[n].q, f.bones[n].q)
        assert g.bones[n].valid == f.bones[n].valid
    tt = TaskTargets.decode(make_targets().encode())
    assert tt.mode == "bounded" and tt.targets["right_elbow"].use_rotation is False
    np.testing.assert_allclose(tt.targets["left_elbow"].p, [2, 2, 2])
    c = JointCommand.decode(make_command().encode())
    assert c.residuals == pytest.approx([1e-4, 2e-3]) and c.iters == 5 and c.t_cmd == 12.5
    s = RobotState.decode(make_state().encode())
    assert s.frames["left_wrist"].p.tolist() == [1, 1, 1] and s.sim_time == 1.5
    st_ = ServiceStatus("sim", "main", "ok", 3.0, {"in": 2.0}, {"received": 4}, {"nan": 1}, "x", {"p50": 0.3})
    assert ServiceStatus.decode(st_.encode()) == st_


def test_header_is_carried_unchanged():
    f = make_frame(seq=42)
    assert HumanFrame.decode(f.encode()).hdr == Header(42, 1.25, f.hdr.t0)


def _mutate(msg, **changes) -> bytes:
    d = msgpack.unpackb(msg.encode())
    d.update(changes)
    return msgpack.packb(d)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"\xc1garbage", "msgpack"),
        (make_frame().encode()[:-7], "msgpack"),
        (msgpack.packb([1, 2, 3]), "type"),
        (_mutate(make_frame(), v=SCHEMA_VERSION + 1), "version"),
        (_mutate(make_frame(), t="RobotState"), "type"),
        (
            _mutate(make_frame(), names=["pelvis", "tail"], p=[[0, 0, 0]] * 2, q=[[1, 0, 0, 0]] * 2, valid=[True] * 2),
            "unknown_name",
        ),
        (_mutate(make_frame(), names=["pelvis"], p=[[0, float("nan"), 0]], q=[[1, 0, 0, 0]], valid=[True]), "nan"),
        (_mutate(make_frame(), names=["pelvis"], p=[[0, 0, 0]], q=[[2, 0, 0, 0]], valid=[True]), "quaternion"),
        (_mutate(make_frame(), names=["pelvis"], p=[[0, 0]], q=[[1, 0, 0, 0]], valid=[True]), "shape"),
        (_mutate(make_frame(), hdr=[1, float("inf"), 3]), "nan"),
        (_mutate(make_frame(), hdr=[-1, 0.0, 3]), "range"),
        (_mutate(make_command(), q=[0.1]), "shape"),
        (_mutate(make_command(), status="exploded"), "unknown_name"),
        (
            _mutate(make_targets(), targets={"left_knee": [[0] * 3, [1, 0, 0, 0], [0] * 3, [0] * 3, True, True]}),
            "unknown_name",
        ),
        (msgpack.packb({"v": 1, "t": "HumanFrame", "names": list(range(100000))}), "msgpack"),
    ],
)
def test_bad_payloads_raise_message_error_with_reason(payload, reason):
    decoder = {b"Joint": JointCommand, b"TaskT": TaskTargets}.get(
        next((k for k in (b"Joint", b"TaskT") if k in payload), None), HumanFrame
    )
    with pytest.raises(MessageError) as err:
        decoder.decode(payload)
    assert err.value.reason == reason, str(err.value)
    assert str(err.value)  # the text says what was wrong


def test_missing_field_is_named():
    d = msgpack.unpackb(make_command().encode())
    del d["q"]
    with pytest.raises(MessageError, match="'q'"):
        JointCommand.decode(msgpack.packb(d))


def test_peek_type():
    assert peek_type(make_state().encode()) == "RobotState"
    assert peek_type(b"\x00\x01") is None


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_random_bytes_never_escape_as_other_errors(data):
    for cls in (HumanFrame, TaskTargets, JointCommand, RobotState, ServiceStatus):
        try:
            cls.decode(data)
        except MessageError:
            pass


_json = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=8),
    lambda c: st.lists(c, max_size=5) | st.dictionaries(st.text(max_size=6), c, max_size=5),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(["hdr", "names", "p", "q", "valid", "root", "src", "joints", "targets"]), _json))
def test_structured_garbage_with_valid_envelope_is_rejected_cleanly(body):
    for cls in (HumanFrame, TaskTargets, JointCommand, RobotState):
        payload = msgpack.packb({"v": SCHEMA_VERSION, "t": cls.TYPE, **body})
        try:
            msg = cls.decode(payload)
        except MessageError:
            continue
        # Anything accepted must be entirely finite.
        for v in msgpack.unpackb(msg.encode()).values():
            if isinstance(v, float):
                assert math.isfinite(v)


def test_task_targets_carry_optional_upper_arms_validated():
    tt = make_targets()
    q = np.array([0.0, 1.0, 0.0, 0.0])
    tt.upper_arms = {"left": q}
    back = TaskTargets.decode(tt.encode())
    np.testing.assert_allclose(back.upper_arms["left"], q)
    assert "right" not in back.upper_arms
    assert TaskTargets.decode(make_targets().encode()).upper_arms == {}  # older publishers: absent
    cases = [
        ({"middle": [1.0, 0, 0, 0]}, "unknown_name"),
        ({"left": [2.0, 0, 0, 0]}, "quaternion"),
        ({"left": [1.0, 0, 0]}, "shape"),
        ({"left": [float("nan"), 0, 0, 1.0]}, "nan"),
        ([1], "type"),
    ]
    for bad, reason in cases:
        d = msgpack.unpackb(make_targets().encode())
        d["ua"] = bad
        with pytest.raises(MessageError) as exc:
            TaskTargets.decode(msgpack.packb(d))
        assert exc.value.reason == reason, (bad, exc.value)


def test_human_frame_says_whether_its_orientations_are_measured():
    # A marker-only source sends oriented=False ("ori"); a payload without the key (older sources) is oriented;
    # anything but a bool is rejected with its reason.
    bones = {"left_wrist": Bone(np.array([0.1, 0.2, 0.3]), np.array([1.0, 0.0, 0.0, 0.0]))}
    frame = HumanFrame(Header(1, 0.1, 5), "c3d:x", Pose(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])), bones, False)
    assert HumanFrame.decode(frame.encode()).oriented is False
    body = frame.body()
    del body["ori"]
    assert HumanFrame.from_body(body).oriented is True
    body["ori"] = 1
    with pytest.raises(MessageError) as err:
        HumanFrame.from_body(body)
    assert err.value.reason == "type" and "ori" in str(err.value)


def test_task_targets_carry_an_optional_waist_validated():
    tt = make_targets()
    tt.waist = np.array([0.1, -0.2, 0.3])
    back = TaskTargets.decode(tt.encode())
    np.testing.assert_allclose(back.waist, [0.1, -0.2, 0.3])
    plain = make_targets()
    assert "wa" not in msgpack.unpackb(plain.encode())  # absent when empty
    assert len(TaskTargets.decode(plain.encode()).waist) == 0  # older publishers: absent
    for bad, reason in (([0.1, float("nan"), 0.0], "nan"), ([0.1, "x"], "type"), (0.3, "type")):
        d = msgpack.unpackb(make_targets().encode())
        d["wa"] = bad
        with pytest.raises(MessageError) as exc:
            TaskTargets.decode(msgpack.packb(d))
        assert exc.value.reason == reason, (bad, exc.value)
