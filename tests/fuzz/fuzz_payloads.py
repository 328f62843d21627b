"""Hypothesis strategies of malformed and adversarial payloads for every message type.

Each payload starts from a valid message of the type (numbers drawn from a
seeded numpy generator, so generation stays fast at 100 000 examples) and is
then damaged by one drawn operator: truncation, byte flips, random bytes,
a field replaced by a value of the wrong type, NaN/inf, huge arrays, wrong
schema version or type tag, unknown names, non-unit quaternions, missing or
extra fields, deep nesting, length mismatches. Some operators leave the
message valid on purpose (extra fields, a quaternion scaled by -1): accepted
messages must then be entirely valid, which :func:`check_payload` verifies.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st

from shared.messages import (
    COMMAND_STATUSES,
    HUMAN_BONES,
    MESSAGE_TYPES,
    QUAT_NORM_TOL,
    SCHEMA_VERSION,
    Bone,
    Header,
    HumanFrame,
    JointCommand,
    Message,
    MessageError,
    Pose,
    RobotState,
    ServiceStatus,
    Target,
    TaskTargets,
)
from shared.targets import TARGET_NAMES

JOINTS = tuple(f"joint_{i}" for i in range(17))


# --------------------------------------------------------------------------- valid messages


def _quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _hdr(rng: np.random.Generator) -> Header:
    return Header(int(rng.integers(0, 1 << 40)), float(rng.uniform(0, 1e4)), int(rng.integers(0, 1 << 62)))


def valid_message(type_name: str, rng: np.random.Generator) -> Message:
    """A random valid message of ``type_name``."""
    if type_name == "HumanFrame":
        names = [n for n in HUMAN_BONES if rng.random() < 0.8]
        bones = {n: Bone(rng.normal(size=3), _quat(rng), bool(rng.random() < 0.9)) for n in names}
        return HumanFrame(_hdr(rng), "fuzz", Pose(rng.normal(size=3), _quat(rng)), bones)
    if type_name == "TaskTargets":
        targets = {
            n: Target(
                rng.normal(size=3), _quat(rng), rng.normal(size=3), rng.normal(size=3), True, bool(rng.random() < 0.5)
            )
            for n in TARGET_NAMES
            if rng.random() < 0.9
        }
        return TaskTargets(_hdr(rng), targets)
    if type_name == "JointCommand":
        n = int(rng.integers(1, len(JOINTS) + 1))
        return JointCommand(
            _hdr(rng),
            "main",
            "hqp",
            list(JOINTS[:n]),
            rng.uniform(-2, 2, n),
            rng.uniform(-1, 1, n),
            list(rng.uniform(0, 1, 3)),
            float(rng.uniform(0, 5)),
            str(rng.choice(COMMAND_STATUSES)),
            int(rng.integers(0, 100)),
            int(rng.integers(0, 10)),
            "",
            float(rng.uniform(0, 100)),
        )
    if type_name == "RobotState":
        n = int(rng.integers(1, len(JOINTS) + 1))
        frames = {t: Pose(rng.normal(size=3), _quat(rng)) for t in TARGET_NAMES}
        return RobotState(_hdr(rng), list(JOINTS[:n]), rng.uniform(-2, 2, n), rng.uniform(-1, 1, n), frames, 1.5)
    if type_name == "ServiceStatus":
        return ServiceStatus(
            "solver",
            "main",
            "ok",
            float(rng.uniform(0, 1e5)),
            {"in.frames": float(rng.uniform(0, 1e3))},
            {"received": int(rng.integers(0, 1 << 40)), "dropped": 3},
            {"nan": 2},
            "",
            {"latency_ms_p50": 0.4},
        )
    raise KeyError(type_name)


# --------------------------------------------------------------------------- adversarial values

_BIG_INTS = (-(2**63), 2**63 - 1, 2**64 - 1, -1, 0, 2**53 + 1)
_BAD_FLOATS = (math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -0.0)


def _huge_list(n: int, kind: int) -> list:
    return [[0.0, 0.0, 0.0, 1.0], 1.0, "pelvis", None][kind % 4 : kind % 4 + 1] * n


weird_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.sampled_from(_BIG_INTS),
    st.integers(-(2**63), 2**64 - 1),
    st.sampled_from(_BAD_FLOATS),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),
    st.text(min_size=300, max_size=5000),
    st.binary(max_size=64),
    st.builds(msgpack.ExtType, st.integers(0, 127), st.binary(max_size=16)),
)

weird_values = st.one_of(
    weird_scalars,
    st.lists(weird_scalars, max_size=6),
    st.dictionaries(st.one_of(st.text(max_size=10), st.integers()), weird_scalars, max_size=4),
    st.builds(_huge_list, st.integers(257, 5000), st.integers(0, 3)),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=3, max_size=4),
)


def _paths(obj: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (tuple of keys/indices) into a nested dict/list body."""
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*prefix, i))
    return out


def _get(obj: Any, path: tuple) -> Any:
    for p in path:
        obj = obj[p]
    return obj


def _set(obj: Any, path: tuple, value: Any) -> None:
    _get(obj, path[:-1])[path[-1]] = value


def _is_quat(x: Any) -> bool:
    return isinstance(x, list) and len(x) == 4 and all(isinstance(v, float) for v in x)


def _pack(d: Any) -> bytes:
    return msgpack.packb(d, use_bin_type=True)


@st.composite
def adversarial_payload(draw: Callable, type_name: str) -> bytes:
    """One malformed or adversarial payload for ``type_name``."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    msg = valid_message(type_name, rng)
    raw = msg.encode()
    d = msgpack.unpackb(raw, raw=False)
    op = draw(
        st.sampled_from(
            (
                "truncate", "flip", "random", "replace", "nonfinite", "quat", "version", "type_tag", "unknown_name",
                "drop", "extra", "huge", "length", "deep", "hdr", "other_type", "valid",
            )
        )
    )  # fmt: skip
    paths = _paths(d)
    if op == "truncate":
        return raw[: draw(st.integers(0, len(raw) - 1))]
    if op == "flip":
        b = bytearray(raw)
        for _ in range(draw(st.integers(1, 8))):
            b[draw(st.integers(0, len(b) - 1))] = draw(st.integers(0, 255))
        return bytes(b)
    if op == "random":
        return draw(st.binary(max_size=512))
    if op == "replace":
        _set(d, draw(st.sampled_from(paths)), draw(weird_values))
    elif op == "nonfinite":
        floats = [p for p in paths if isinstance(_get(d, p), float)] or paths
        for p in draw(st.lists(st.sampled_from(floats), min_size=1, max_size=3)):
            _set(d, p, draw(st.sampled_from((math.nan, math.inf, -math.inf))))
    elif op == "quat":
        quats = [p for p in paths if _is_quat(_get(d, p))]
        if quats:
            p = draw(st.sampled_from(quats))
            scale = draw(st.sampled_from((0.0, 0.5, 0.999, 1.0005, 1.01, 2.0, -1.0, 1e6, 1e-9)))
            _set(d, p, [v * scale for v in _get(d, p)])
    elif op == "version":
        d["v"] = draw(st.one_of(st.integers(-5, 5).filter(lambda v: v != SCHEMA_VERSION), weird_scalars))
    elif op == "type_tag":
        d["t"] = draw(st.one_of(st.sampled_from(sorted(MESSAGE_TYPES)), weird_scalars))
    elif op == "unknown_name":
        name = draw(st.one_of(st.text(max_size=20), st.sampled_from(("left_hand_tip", "pelvis", "left_wrist", ""))))
        holders = [p for p in paths if isinstance(_get(d, p), str) and p[0] in ("names", "joints")]
        if holders:
            _set(d, draw(st.sampled_from(holders)), name)
        for key in ("targets", "frames"):
            if isinstance(d.get(key), dict) and d[key]:
                old = draw(st.sampled_from(sorted(d[key])))
                d[key][name] = d[key].pop(old)
    elif op == "drop":
        d.pop(draw(st.sampled_from(sorted(d))))
    elif op == "extra":
        d[draw(st.text(max_size=12))] = draw(weird_values)
    elif op == "huge":
        lists = [p for p in paths if isinstance(_get(d, p), list)] or [()]
        n = draw(st.sampled_from((257, 1025, 70_000, 200_000)))
        big = [1.0] * n
        if lists == [()]:
            return _pack(big)
        _set(d, draw(st.sampled_from(lists)), big)
    elif op == "length":
        lists = [p for p in paths if isinstance(_get(d, p), list) and _get(d, p)]
        if lists:
            lst = _get(d, draw(st.sampled_from(lists)))
            if draw(st.booleans()):
                lst.pop()
            else:
                lst.append(lst[-1])
    elif op == "deep":
        depth = draw(st.integers(100, 3000))
        nested: Any = 1.0
        for _ in range(depth):
            nested = [nested]
        try:
            return _pack(nested) if draw(st.booleans()) else _pack({**d, "p": nested})
        except (ValueError, RecursionError):  # deeper than msgpack can pack: send raw nested fixarrays
            return b"\x91" * depth + b"\x01"
    elif op == "hdr":
        if "hdr" in d:
            i = draw(st.integers(0, 2))
            d["hdr"][i] = draw(st.one_of(st.sampled_from((-1, -(2**63), 2**64 - 1)), st.sampled_from(_BAD_FLOATS)))
    elif op == "other_type":
        other = draw(st.sampled_from(sorted(MESSAGE_TYPES)))
        return valid_message(other, rng).encode()
    try:
        return _pack(d)
    except (OverflowError, ValueError, TypeError):
        return raw[: len(raw) // 2]


@st.composite
def backwards_sequence(draw: Callable, length: int = 20) -> list[bytes]:
    """HumanFrames whose ``hdr.seq``/``hdr.stamp`` go backwards somewhere (service-level check)."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    seqs = draw(st.lists(st.integers(0, 1000), min_size=length, max_size=length).filter(lambda s: s != sorted(s)))
    out = []
    for s in seqs:
        f = valid_message("HumanFrame", rng)
        f.hdr = Header(s, s / 100.0)
        out.append(f.encode())
    return out


def for_each_drawn(strategy: st.SearchStrategy, n: int, fn: Callable[[Any], None], rng_seed: int = 0) -> None:
    """Call ``fn`` on ``n`` values drawn from ``strategy``, as a fuzz run (not a test) wants them.

    Seeded (the same values every run), generation only: no shrinking, no example database,
    no deadline, no health checks (adversarial strategies are slow and filter a lot on purpose).
    """

    @seed(rng_seed)
    @settings(
        max_examples=n, database=None, deadline=None, phases=[Phase.generate], suppress_health_check=list(HealthCheck)
    )
    @given(strategy)
    def run(value: Any) -> None:
        fn(value)

    run()


# --------------------------------------------------------------------------- oracle


def _finite(a: Any, shape: tuple | None = None) -> None:
    arr = np.asarray(a, dtype=float)
    assert np.all(np.isfinite(arr)), f"non-finite accepted: {arr}"
    if shape is not None:
        assert arr.shape == shape, f"shape {arr.shape} != {shape}"


def _unit(q: Any) -> None:
    _finite(q, (4,))
    assert abs(np.linalg.norm(q) - 1.0) <= QUAT_NORM_TOL, f"non-unit quaternion accepted: {q}"


def _pose(p: Pose) -> None:
    _finite(p.p, (3,))
    _unit(p.q)


def assert_valid(msg: Message) -> None:
    """Everything in an accepted message is finite, well-shaped, named and unit where it must be."""
    if hasattr(msg, "hdr"):
        assert msg.hdr.seq >= 0 and msg.hdr.t0 >= 0
        _finite([msg.hdr.stamp])
    if isinstance(msg, HumanFrame):
        _pose(msg.root)
        assert set(msg.bones) <= set(HUMAN_BONES)
        for b in msg.bones.values():
            _pose(Pose(b.p, b.q))
            assert isinstance(b.valid, bool)
    elif isinstance(msg, TaskTargets):
        assert set(msg.targets) <= set(TARGET_NAMES)
        for t in msg.targets.values():
            _pose(Pose(t.p, t.q))
            _finite(t.v, (3,))
            _finite(t.w, (3,))
    elif isinstance(msg, JointCommand):
        n = len(msg.joints)
        assert len(set(msg.joints)) == n and all(isinstance(j, str) for j in msg.joints)
        _finite(msg.q, (n,))
        _finite(msg.qd, (n,))
        _finite(msg.residuals)
        _finite([msg.solve_ms, msg.t_cmd])
        assert msg.status in COMMAND_STATUSES
    elif isinstance(msg, RobotState):
        n = len(msg.joints)
        _finite(msg.q, (n,))
        _finite(msg.qd, (n,))
        _finite([msg.sim_time])
        assert set(msg.frames) <= set(TARGET_NAMES)
        for p in msg.frames.values():
            _pose(p)
    elif isinstance(msg, ServiceStatus):
        _finite([msg.uptime, *msg.rates.values(), *msg.extra.values()])
        assert all(isinstance(v, int) for v in (*msg.counts.values(), *msg.rejects.values()))
    # What a service accepts it forwards: the re-encoded message must decode again.
    type(msg).decode(msg.encode())


def check_payload(cls: type[Message], payload: bytes) -> str:
    """Decode ``payload`` as ``cls``: ``"accepted"``, ``"rejected:<reason>"``.

    Raises:
        AssertionError: an accepted message is invalid.
        Exception: anything but MessageError escaping the decoder (a crash).
    """
    try:
        msg = cls.decode(payload)
    except MessageError as exc:
        return f"rejected:{exc.reason}"
    assert_valid(msg)
    return "accepted"
