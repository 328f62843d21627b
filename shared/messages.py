"""Message contracts of the mimic bus: one module, msgpack on the wire.

Every message is a msgpack map with:

* ``v``   schema version (int, must equal :data:`SCHEMA_VERSION`);
* ``t``   message type name (``"HumanFrame"``, ...);
* ``hdr`` the :class:`Header` of the mocap frame the message derives from
  (``seq``, source ``stamp`` [s] and ``t0`` wall-clock origin [ns]), copied
  unchanged by every downstream service so that latency and drops can be
  measured at any point of the pipeline.

Arrays travel as plain msgpack lists of floats, so any language can publish.
Poses are position ``p`` (3,) [m] and unit quaternion ``q`` (4,) ``w, x, y, z``.

Decoding validates everything (types, shapes, finite numbers, unit
quaternions, known names, version). Any problem raises :class:`MessageError`,
whose text says what was wrong and whose ``reason`` is a short stable tag
that services count in their :class:`ServiceStatus`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import Any, ClassVar

import msgpack
import numpy as np

from shared.targets import SIDES, TARGET_NAMES

SCHEMA_VERSION = 1

#: Largest payload any decoder accepts [bytes]; bigger ones are rejected
#: before msgpack allocates anything.
MAX_PAYLOAD_BYTES = 1 << 20
#: Largest array length accepted anywhere in a message.
MAX_ITEMS = 256
#: Longest string or binary field [bytes].
MAX_STR_BYTES = 4096
#: Tolerance on ``|q| == 1`` for quaternions on the wire.
QUAT_NORM_TOL = 1e-3

#: Canonical human bones (the skeleton maps of ingest map rigs onto these).
HUMAN_BONES: tuple[str, ...] = (
    "pelvis",
    "spine",
    "chest",
    "neck",
    "head",
    *(f"{side}_{bone}" for side in SIDES for bone in ("clavicle", "shoulder", "elbow", "wrist", "hand")),
)
#: Command status values a solver may report (``collision``: the wrists are held at the safety
#: distance from the body, their target being inside it or behind it; ``surface``: the wrist level is
#: met on a wrist target the solver moved onto the trunk's surface, the published one being inside it).
COMMAND_STATUSES: tuple[str, ...] = ("ok", "infeasible", "held", "failed", "init", "collision", "surface")


class MessageError(ValueError):
    """A payload that is not a valid message.

    Attributes:
        reason: short stable tag (``"msgpack"``, ``"version"``, ``"nan"``, ...)
            used as a counter key in ServiceStatus.
    """

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


# --------------------------------------------------------------------------- validation helpers


def _req(d: dict, key: str, where: str) -> Any:
    if key not in d:
        raise MessageError("missing", f"{where}: missing field '{key}'")
    return d[key]


def _int(x: Any, where: str, lo: int = 0, hi: int = 2**63 - 1) -> int:
    if isinstance(x, bool) or not isinstance(x, int):
        raise MessageError("type", f"{where}: expected int, got {type(x).__name__}")
    if not lo <= x <= hi:
        raise MessageError("range", f"{where}: {x} outside [{lo}, {hi}]")
    return x


def _float(x: Any, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise MessageError("type", f"{where}: expected number, got {type(x).__name__}")
    x = float(x)
    if not math.isfinite(x):
        raise MessageError("nan", f"{where}: not finite ({x})")
    return x


def _str(x: Any, where: str, max_len: int = 256) -> str:
    if not isinstance(x, str):
        raise MessageError("type", f"{where}: expected str, got {type(x).__name__}")
    if len(x) > max_len:
        raise MessageError("range", f"{where}: string longer than {max_len}")
    return x


def _list(x: Any, where: str, max_len: int = MAX_ITEMS) -> list:
    if not isinstance(x, (list, tuple)):
        raise MessageError("type", f"{where}: expected list, got {type(x).__name__}")
    if len(x) > max_len:
        raise MessageError("size", f"{where}: {len(x)} items, at most {max_len}")
    return list(x)


def _vec(x: Any, where: str, n: int | None = None) -> np.ndarray:
    """A finite float vector of length ``n`` (any length when None).

    Checked in plain Python, not numpy: the vectors are short (3-4 numbers, 29 joints) and a
    TaskTargets holds 16 of them, where numpy's per-call overhead made decoding cost ~0.3 ms
    on every hop.
    """
    items = _list(x, where)
    if n is not None and len(items) != n:
        raise MessageError("shape", f"{where}: expected {n} numbers, got {len(items)}")
    for i, v in enumerate(items):
        if type(v) is not float and type(v) is not int and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise MessageError("type", f"{where}[{i}]: expected number, got {type(v).__name__}")
    arr = np.array(items, dtype=float)
    if not all(map(math.isfinite, items)):
        raise MessageError("nan", f"{where}: contains NaN or inf")
    return arr


def _matrix(x: Any, where: str, rows: int, cols: int, names: list[str] | None = None) -> np.ndarray:
    """A finite (rows, cols) float matrix from a list of lists (vectorised: the hot path)."""
    items = _list(x, where)
    if len(items) != rows:
        raise MessageError("shape", f"{where}: expected {rows} rows, got {len(items)}")
    for i, row in enumerate(items):
        if not isinstance(row, (list, tuple)) or len(row) != cols:
            label = names[i] if names else i
            raise MessageError("shape", f"{where}[{label}]: expected {cols} numbers, got {row!r}"[:200])
        for v in row:
            if type(v) is not float and (type(v) is not int):
                raise MessageError(
                    "type", f"{where}[{names[i] if names else i}]: expected number, got {type(v).__name__}"
                )
    arr = np.array(items, dtype=float).reshape(rows, cols)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise MessageError("nan", f"{where}[{names[i] if names else i}]: contains NaN or inf")
    return arr


def _quats(x: Any, where: str, rows: int, names: list[str] | None = None) -> np.ndarray:
    """(rows, 4) unit quaternions, normalised."""
    q = _matrix(x, where, rows, 4, names)
    with np.errstate(over="ignore"):
        norms = np.linalg.norm(q, axis=1)
    bad = np.abs(norms - 1.0) > QUAT_NORM_TOL
    if bad.any():
        i = int(np.argmax(bad))
        label = names[i] if names else i
        raise MessageError(
            "quaternion", f"{where}[{label}]: quaternion norm {norms[i]:.6f} is not 1 (w, x, y, z expected)"
        )
    return q / norms[:, None]


#: Beyond this a quaternion component's square overflows in the norm (which is then far from 1 anyway).
_QUAT_COMPONENT_MAX = 1e150


def _quat(x: Any, where: str) -> np.ndarray:
    q = _vec(x, where, 4)
    # sqrt(q.q) is np.linalg.norm's own formula, without its overhead (and without np.errstate's:
    # huge finite components are rejected before they can overflow).
    norm = math.sqrt(q.dot(q)) if max(map(abs, x)) < _QUAT_COMPONENT_MAX else math.inf
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise MessageError("quaternion", f"{where}: quaternion norm {norm:.6f} is not 1 (w, x, y, z expected)")
    return q / norm


def _dict(x: Any, where: str) -> dict:
    if not isinstance(x, dict):
        raise MessageError("type", f"{where}: expected map, got {type(x).__name__}")
    return x


def _bool(x: Any, where: str) -> bool:
    if not isinstance(x, bool):
        raise MessageError("type", f"{where}: expected bool")
    return x


def _table(x: Any, where: str, known: tuple[str, ...]) -> dict:
    """A map keyed by unique names out of ``known`` (its values are the caller's to check)."""
    raw = _dict(x, where)
    _names(list(raw), where, known)
    return raw


def _names(x: Any, where: str, known: tuple[str, ...] | None) -> list[str]:
    names = [_str(n, f"{where}[{i}]") for i, n in enumerate(_list(x, where))]
    if len(set(names)) != len(names):
        raise MessageError("duplicate", f"{where}: duplicated names")
    if known is not None:
        unknown = [n for n in names if n not in known]
        if unknown:
            raise MessageError("unknown_name", f"{where}: unknown names {unknown}; known: {list(known)}")
    return names


def _fl(a: np.ndarray) -> list[float]:
    # tolist() converts in C: the same Python floats as a per-element float(), several times faster
    # (every message on the bus is encoded through here, on the services' hot paths).
    return np.asarray(a, dtype=float).ravel().tolist()


def _joints_to_wire(joints: list[str], q: np.ndarray, qd: np.ndarray) -> dict:
    """Wire fields of a named joint vector: names, q (n,) [rad], qd (n,) [rad/s]."""
    return {"joints": list(joints), "q": _fl(q), "qd": _fl(qd)}


def _joints_from_wire(d: dict, where: str) -> tuple[Header, list[str], np.ndarray, np.ndarray]:
    """(header, joints, q (n,), qd (n,)) of a message body: unique names, q and qd of the same length."""
    joints = _names(_req(d, "joints", where), "joints", None)
    q = _vec(_req(d, "q", where), "q", len(joints))
    qd = _vec(_req(d, "qd", where), "qd", len(joints))
    return Header.from_wire(_req(d, "hdr", where)), joints, q, qd


# --------------------------------------------------------------------------- building blocks


@dataclass(slots=True)
class Header:
    """Identity of the mocap frame a message derives from.

    Attributes:
        seq: mocap frame sequence number, strictly increasing per source.
        stamp: source timestamp [s] (clip time or device clock).
        t0: wall-clock time the frame entered the bus [ns since epoch]; end-to-end
            latency anywhere is ``time.time_ns() - t0``.
    """

    seq: int
    stamp: float
    t0: int = field(default_factory=time.time_ns)

    def to_wire(self) -> list:
        return [self.seq, self.stamp, self.t0]

    @classmethod
    def from_wire(cls, x: Any) -> Header:
        items = _list(x, "hdr", 3)
        if len(items) != 3:
            raise MessageError("shape", "hdr: expected [seq, stamp, t0]")
        return cls(_int(items[0], "hdr.seq"), _float(items[1], "hdr.stamp"), _int(items[2], "hdr.t0"))


@dataclass(slots=True)
class Pose:
    """Rigid pose: position ``p`` (3,) [m] and unit quaternion ``q`` (4,) wxyz."""

    p: np.ndarray
    q: np.ndarray

    def to_wire(self) -> list:
        return [_fl(self.p), _fl(self.q)]

    @classmethod
    def from_wire(cls, x: Any, where: str) -> Pose:
        items = _list(x, where, 2)
        if len(items) != 2:
            raise MessageError("shape", f"{where}: expected [p, q]")
        return cls(_vec(items[0], f"{where}.p", 3), _quat(items[1], f"{where}.q"))


def _check_version_and_type(d: dict, type_name: str) -> None:
    v = d.get("v")
    if v != SCHEMA_VERSION:
        raise MessageError("version", f"schema version {v!r}, this build speaks {SCHEMA_VERSION}")
    t = d.get("t")
    if t != type_name:
        raise MessageError("type", f"message type {t!r}, expected {type_name!r}")


def unpack(payload: bytes | bytearray | memoryview) -> Any:
    """msgpack bytes -> Python objects, within the bus limits (the one msgpack decoder of mimic).

    Limits: ``MAX_PAYLOAD_BYTES`` in all, ``MAX_ITEMS * 4`` array items, ``MAX_ITEMS`` map
    entries, ``MAX_STR_BYTES`` per string and binary; map keys must be str or bytes.

    Raises:
        MessageError: "size" (too large) or "msgpack" (not valid msgpack or over a limit).
    """
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MessageError("size", f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    try:
        return msgpack.unpackb(
            bytes(payload),
            raw=False,
            strict_map_key=True,
            max_array_len=MAX_ITEMS * 4,
            max_map_len=MAX_ITEMS,
            max_str_len=MAX_STR_BYTES,
            max_bin_len=MAX_STR_BYTES,
        )
    except Exception as exc:  # msgpack raises a zoo of types on garbage
        raise MessageError("msgpack", f"not valid msgpack ({type(exc).__name__}: {exc})") from None


def unpack_message(payload: bytes | bytearray | memoryview, type_name: str) -> dict:
    """:func:`unpack` a message's top-level map and check its schema version and type name.

    Raises:
        MessageError: as :func:`unpack`, or "type"/"version" for a wrong map, type or version.
    """
    d = _dict(unpack(payload), type_name or "message")
    _check_version_and_type(d, type_name)
    return d


def peek(payload: bytes | bytearray | memoryview) -> dict | None:
    """The top-level map of a payload, unvalidated (None if unreadable or not a map); never raises."""
    try:
        d = unpack(payload)
    except MessageError:
        return None
    return d if isinstance(d, dict) else None


def restamp(payload: bytes, t0_ns: int) -> bytes:
    """``payload`` with its header's ``t0`` (bus entry, wall clock [ns]) set to ``t0_ns``.

    A replayed message enters the bus again: with its recorded ``t0`` it would look older than
    the stream it joins (latency figures wrong, and a receiver could not tell a replay starting
    over from a late packet). Payloads without a ``hdr`` are returned unchanged.
    """
    d = peek(payload)
    if d is None or not isinstance(d.get("hdr"), list) or len(d["hdr"]) != 3:
        return payload
    d["hdr"][2] = int(t0_ns)
    return msgpack.packb(d, use_bin_type=True)


#: Largest query payload (hand-typed commands and small maps) [bytes].
MAX_QUERY_BYTES = 64 * 1024


def parse_query(payload: bytes | bytearray | memoryview) -> Any:
    """A queryable's payload as people and programs send it: msgpack, JSON or plain text, in that order.

    Returns:
        the unpacked value (a map, list or str); text is stripped. A payload that is valid
        msgpack but neither a str, map nor list (one printable byte is: ``b"b"`` unpacks to 98)
        is read as text.

    Raises:
        MessageError: "size" above ``MAX_QUERY_BYTES``.
    """
    if len(payload) > MAX_QUERY_BYTES:
        raise MessageError("size", f"query payload of {len(payload)} bytes exceeds {MAX_QUERY_BYTES}")
    raw = bytes(payload)
    try:
        value = unpack(raw)
    except MessageError:
        try:
            value = json.loads(raw.decode())
        except (UnicodeDecodeError, json.JSONDecodeError):
            value = None
    if not isinstance(value, (str, dict, list)):
        value = raw.decode(errors="replace").strip()
    return value


class Message:
    """Base of all bus messages: ``encode()`` and ``decode(payload)``."""

    TYPE: ClassVar[str] = ""

    def body(self) -> dict:  # pragma: no cover - overridden
        raise NotImplementedError

    @classmethod
    def from_body(cls, d: dict):  # pragma: no cover - overridden
        raise NotImplementedError

    def encode(self) -> bytes:
        """Serialise to msgpack bytes."""
        d = {"v": SCHEMA_VERSION, "t": self.TYPE}
        d.update(self.body())
        return msgpack.packb(d, use_bin_type=True)

    @classmethod
    def decode(cls, payload: bytes | bytearray | memoryview):
        """Parse and validate a payload.

        Raises:
            MessageError: whatever is wrong with it, never anything else.
        """
        d = unpack_message(payload, cls.TYPE)
        try:
            return cls.from_body(d)
        except MessageError:
            raise
        except (TypeError, ValueError, KeyError, IndexError, AttributeError) as exc:
            raise MessageError("invalid", f"{cls.TYPE}: {type(exc).__name__}: {exc}") from None


# --------------------------------------------------------------------------- messages


@dataclass(slots=True)
class Bone:
    """One human bone in the operator's root (pelvis) frame."""

    p: np.ndarray  # (3,) [m], pelvis frame
    q: np.ndarray  # (4,) wxyz, orientation of the bone frame in the pelvis frame
    valid: bool = True


@dataclass(slots=True)
class HumanFrame(Message):
    """Operator pose at one instant (``mimic/<s>/mocap/frame``).

    Attributes:
        hdr: frame identity; ``hdr.seq`` is set by the source.
        source: free text naming the source ("bvh:clip.bvh", "xsens", ...).
        root: pelvis pose in the world frame of the capture.
        bones: canonical bone name -> :class:`Bone` in the pelvis frame
            (``T_h^w = (T_w^h)^-1 T_w^e``, seed 000 section 1.2).
        oriented: False when the bones' orientations are placeholders (a marker-only source such as
            C3D gives positions only; its quaternions are identity): the retargeter then publishes the
            wrists without an orientation to track (``use_rotation=False``). Wire key ``ori``, optional
            (absent: True).
    """

    TYPE: ClassVar[str] = "HumanFrame"
    hdr: Header
    source: str
    root: Pose
    bones: dict[str, Bone]
    oriented: bool = True

    def body(self) -> dict:
        names = list(self.bones)
        return {
            "hdr": self.hdr.to_wire(),
            "src": self.source,
            "root": self.root.to_wire(),
            "names": names,
            "p": [_fl(self.bones[n].p) for n in names],
            "q": [_fl(self.bones[n].q) for n in names],
            "valid": [bool(self.bones[n].valid) for n in names],
            "ori": bool(self.oriented),
        }

    @classmethod
    def from_body(cls, d: dict) -> HumanFrame:
        names = _names(_req(d, "names", "HumanFrame"), "names", HUMAN_BONES)
        ps = _list(_req(d, "p", "HumanFrame"), "p")
        qs = _list(_req(d, "q", "HumanFrame"), "q")
        valid = _list(_req(d, "valid", "HumanFrame"), "valid")
        if not len(ps) == len(qs) == len(valid) == len(names):
            raise MessageError(
                "shape", f"names/p/q/valid lengths differ: {len(names)}/{len(ps)}/{len(qs)}/{len(valid)}"
            )
        if any(type(v) is not bool for v in valid):
            raise MessageError("type", "valid: expected bools")
        P = _matrix(ps, "p", len(names), 3, names)
        Q = _quats(qs, "q", len(names), names)
        bones = {n: Bone(P[i], Q[i], valid[i]) for i, n in enumerate(names)}
        oriented = d.get("ori", True)
        if type(oriented) is not bool:
            raise MessageError("type", f"ori: expected a bool, got {type(oriented).__name__}")
        return cls(
            Header.from_wire(_req(d, "hdr", "HumanFrame")),
            _str(_req(d, "src", "HumanFrame"), "src"),
            Pose.from_wire(_req(d, "root", "HumanFrame"), "root"),
            bones,
            oriented,
        )


@dataclass(slots=True)
class Target:
    """One retargeted task target, robot base frame.

    Attributes:
        p: (3,) position [m]. q: (4,) orientation wxyz (identity when unused).
        v: (3,) linear velocity [m/s]. w: (3,) angular velocity [rad/s].
        valid: False when the source bones were invalid (solver holds the task).
        use_rotation: whether ``q``/``w`` are meaningful for this target.
    """

    p: np.ndarray
    q: np.ndarray
    v: np.ndarray
    w: np.ndarray
    valid: bool = True
    use_rotation: bool = True


@dataclass(slots=True)
class TaskTargets(Message):
    """Wrist and elbow targets (``mimic/<s>/retarget/targets``).

    Attributes:
        upper_arms: optional, side (``left``/``right``) -> (4,) wxyz orientation, robot base frame,
            that the robot's upper-arm link takes when it copies the operator's upper arm (seed 004
            eq. 6's ``R_m``). Present only for sides whose shoulder, elbow and wrist the source gave
            (wire key ``ua``; absent from older publishers, which stay valid).
        waist: optional, (n,) [rad] the robot's waist joint angles (profile ``waist`` order; G1: yaw, roll, pitch)
            that turn its torso as the operator's chest turned relative to their pelvis since the calibration
            (``services.retarget.torso``), clipped into the joints' ranges. Empty (wire key ``wa`` absent) when the
            source gave no measured chest orientation (wrist-only sources, marker-only C3D) and from older
            publishers. With ``SolverConfig.waist_follow_cost`` the strict solvers pull the waist towards it.
    """

    TYPE: ClassVar[str] = "TaskTargets"
    hdr: Header
    targets: dict[str, Target]
    mode: str = "absolute"
    upper_arms: dict[str, np.ndarray] = field(default_factory=dict)
    waist: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def body(self) -> dict:
        d = {
            "hdr": self.hdr.to_wire(),
            "mode": self.mode,
            "targets": {
                n: [_fl(t.p), _fl(t.q), _fl(t.v), _fl(t.w), bool(t.valid), bool(t.use_rotation)]
                for n, t in self.targets.items()
            },
        }
        if self.upper_arms:
            d["ua"] = {s: _fl(q) for s, q in self.upper_arms.items()}
        if len(self.waist):
            d["wa"] = _fl(self.waist)
        return d

    @classmethod
    def from_body(cls, d: dict) -> TaskTargets:
        raw = _table(_req(d, "targets", "TaskTargets"), "targets", TARGET_NAMES)
        targets = {}
        for n, t in raw.items():
            items = _list(t, f"targets.{n}", 6)
            if len(items) != 6:
                raise MessageError("shape", f"targets.{n}: expected [p, q, v, w, valid, use_rotation]")
            if not isinstance(items[4], bool) or not isinstance(items[5], bool):
                raise MessageError("type", f"targets.{n}: valid/use_rotation must be bool")
            targets[n] = Target(
                _vec(items[0], f"{n}.p", 3),
                _quat(items[1], f"{n}.q"),
                _vec(items[2], f"{n}.v", 3),
                _vec(items[3], f"{n}.w", 3),
                items[4],
                items[5],
            )
        upper_arms = {s: _quat(q, f"ua.{s}") for s, q in _table(d.get("ua", {}), "ua", SIDES).items()}
        waist = _vec(d["wa"], "wa") if "wa" in d else np.zeros(0)
        return cls(
            Header.from_wire(_req(d, "hdr", "TaskTargets")),
            targets,
            _str(d.get("mode", "absolute"), "mode"),
            upper_arms,
            waist,
        )


@dataclass(slots=True)
class JointCommand(Message):
    """Solver output (``mimic/<s>/solver/<id>/command``).

    Attributes:
        joints: controlled joint names, (n,).
        q: (n,) commanded positions [rad]. qd: (n,) commanded velocities [rad/s].
        residuals: per priority level, the task residual norm after solving.
        solve_ms: time of the solve including task construction [ms].
        status: one of :data:`COMMAND_STATUSES`.
        iters: QP iterations summed over levels. active: active limit count.
        reason: human-readable why, when status is not ``ok``.
        t_cmd: solver clock time of this command [s].
    """

    TYPE: ClassVar[str] = "JointCommand"
    hdr: Header
    solver_id: str
    algo: str
    joints: list[str]
    q: np.ndarray
    qd: np.ndarray
    residuals: list[float] = field(default_factory=list)
    solve_ms: float = 0.0
    status: str = "ok"
    iters: int = 0
    active: int = 0
    reason: str = ""
    t_cmd: float = 0.0

    def body(self) -> dict:
        return {
            "hdr": self.hdr.to_wire(),
            "id": self.solver_id,
            "algo": self.algo,
            **_joints_to_wire(self.joints, self.q, self.qd),
            "res": [float(r) for r in self.residuals],
            "ms": float(self.solve_ms),
            "status": self.status,
            "iters": int(self.iters),
            "active": int(self.active),
            "reason": self.reason,
            "tc": float(self.t_cmd),
        }

    @classmethod
    def from_body(cls, d: dict) -> JointCommand:
        hdr, joints, q, qd = _joints_from_wire(d, "JointCommand")
        status = _str(_req(d, "status", "JointCommand"), "status")
        if status not in COMMAND_STATUSES:
            raise MessageError("unknown_name", f"status {status!r}; known: {list(COMMAND_STATUSES)}")
        return cls(
            hdr,
            _str(_req(d, "id", "JointCommand"), "id", 64),
            _str(_req(d, "algo", "JointCommand"), "algo", 64),
            joints,
            q,
            qd,
            list(_vec(d.get("res", []), "res")),
            _float(d.get("ms", 0.0), "ms"),
            status,
            _int(d.get("iters", 0), "iters"),
            _int(d.get("active", 0), "active"),
            _str(d.get("reason", ""), "reason", 1024),
            _float(d.get("tc", 0.0), "tc"),
        )


@dataclass(slots=True)
class RobotState(Message):
    """Simulated robot state (``mimic/<s>/sim/state``).

    Attributes:
        hdr: header of the JointCommand last applied.
        joints, q (n,) [rad], qd (n,) [rad/s]: controlled joints.
        frames: achieved poses of ``TARGET_NAMES`` in the robot base frame.
        sim_time: simulated time [s]. solver_id: id being followed.
        holding: True while the watchdog holds the last pose.
    """

    TYPE: ClassVar[str] = "RobotState"
    hdr: Header
    joints: list[str]
    q: np.ndarray
    qd: np.ndarray
    frames: dict[str, Pose]
    sim_time: float
    solver_id: str = "main"
    holding: bool = False

    def body(self) -> dict:
        return {
            "hdr": self.hdr.to_wire(),
            **_joints_to_wire(self.joints, self.q, self.qd),
            "frames": {n: p.to_wire() for n, p in self.frames.items()},
            "ts": float(self.sim_time),
            "id": self.solver_id,
            "hold": bool(self.holding),
        }

    @classmethod
    def from_body(cls, d: dict) -> RobotState:
        hdr, joints, q, qd = _joints_from_wire(d, "RobotState")
        frames = _table(_req(d, "frames", "RobotState"), "frames", TARGET_NAMES)
        return cls(
            hdr,
            joints,
            q,
            qd,
            {n: Pose.from_wire(v, f"frames.{n}") for n, v in frames.items()},
            _float(_req(d, "ts", "RobotState"), "ts"),
            _str(d.get("id", "main"), "id", 64),
            _bool(d.get("hold", False), "hold"),
        )


@dataclass(slots=True)
class ServiceStatus(Message):
    """Health of one service (``mimic/<s>/<service>/status``).

    Attributes:
        service: service name; instance: instance id (e.g. solver id).
        state: "ok", "holding", "degraded" or "stopping".
        uptime: [s]. rates: stream name -> messages per second.
        counts: "received", "published", "dropped", "rejected" ... -> totals.
        rejects: reason tag -> count of rejected inputs.
        last_error: text of the last rejected input or failure.
        extra: service-specific figures (latency percentiles, ...).
        outcomes: result tag -> count of the service's own results (e.g. the solver's
            JointCommand status "ok", "infeasible", "held"); not messages received.
    """

    TYPE: ClassVar[str] = "ServiceStatus"
    service: str
    instance: str
    state: str
    uptime: float
    rates: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    rejects: dict[str, int] = field(default_factory=dict)
    last_error: str = ""
    extra: dict[str, float] = field(default_factory=dict)
    outcomes: dict[str, int] = field(default_factory=dict)

    def body(self) -> dict:
        return {
            "outc": {k: int(v) for k, v in self.outcomes.items()},
            "svc": self.service,
            "inst": self.instance,
            "state": self.state,
            "up": float(self.uptime),
            "rates": {k: float(v) for k, v in self.rates.items()},
            "counts": {k: int(v) for k, v in self.counts.items()},
            "rejects": {k: int(v) for k, v in self.rejects.items()},
            "err": self.last_error,
            "extra": {k: float(v) for k, v in self.extra.items()},
        }

    @classmethod
    def from_body(cls, d: dict) -> ServiceStatus:
        def fmap(x, where, conv):
            m = _dict(x, where)
            return {_str(k, f"{where} key", 64): conv(v, f"{where}.{k}") for k, v in m.items()}

        return cls(
            _str(_req(d, "svc", "ServiceStatus"), "svc", 64),
            _str(_req(d, "inst", "ServiceStatus"), "inst", 64),
            _str(_req(d, "state", "ServiceStatus"), "state", 32),
            _float(_req(d, "up", "ServiceStatus"), "up"),
            fmap(d.get("rates", {}), "rates", _float),
            fmap(d.get("counts", {}), "counts", _int),
            fmap(d.get("rejects", {}), "rejects", _int),
            _str(d.get("err", ""), "err", 4096),
            fmap(d.get("extra", {}), "extra", _float),
            fmap(d.get("outc", {}), "outcomes", _int),
        )


MESSAGE_TYPES: dict[str, type[Message]] = {
    c.TYPE: c for c in (HumanFrame, TaskTargets, JointCommand, RobotState, ServiceStatus)
}


def peek_type(payload: bytes) -> str | None:
    """Message type name of a payload without full validation (None if unreadable)."""
    d = peek(payload)
    return None if d is None else d.get("t")


def peek_header(payload: bytes) -> Header | None:
    """Header of any message without validating the rest (None if unreadable).

    For observers (benchmarks, monitors) that only need ``seq`` and ``t0`` at high rate;
    services decode fully.
    """
    d = peek(payload)
    if d is None or "hdr" not in d:
        return None
    try:
        return Header.from_wire(d["hdr"])
    except Exception:
        return None
