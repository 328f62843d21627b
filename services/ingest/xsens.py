"""Xsens MVN real-time network streaming: pose datagrams (type 02, quaternion) -> HumanFrame.

Implemented from the public "MVN real-time network streaming protocol
specification" (Xsens document MV0305P). All fields are big-endian.

Header, 24 bytes::

    ID string        6  b"MXTP02" ("MXTP" + message type "02")
    sample counter   4  uint32
    datagram counter 1  uint8; bit 7 set on the last datagram of a sample
    number of items  1  uint8; segments in this datagram
    time code        4  uint32 [ms since the start of the capture]
    character ID     1  uint8
    body segments    1  uint8
    props            1  uint8
    finger segments  1  uint8
    reserved         2
    payload size     2  uint16 [bytes after the header]

Type 02 item, 32 bytes: segment ID int32, position x, y, z float32 (global
Z-up MVN frame; centimetres in the specification revision this follows, some
MVN releases stream metres, hence ``units``), orientation q1..q4 float32
(w, x, y, z; segment frame in the global frame). Segment IDs 1..23:
Pelvis, L5, L3, T12, T8, Neck, Head, RightShoulder, RightUpperArm,
RightForeArm, RightHand, LeftShoulder, LeftUpperArm, LeftForeArm, LeftHand,
then the legs. A segment's origin is its proximal joint, and in the MVN
calibration pose every segment frame is aligned with the global frame
(x forward, y left, z up), so the Pelvis frame is directly our pelvis frame.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from services.ingest.body_frame import UNIT_SCALES
from services.ingest.rotations import matrices_to_quats, quats_to_matrices
from shared.messages import Bone, Header, HumanFrame, Pose

HEADER = struct.Struct(">6sIBBIBBBBHH")
QUAT_ITEM = struct.Struct(">i3f4f")
assert HEADER.size == 24 and QUAT_ITEM.size == 32

SEGMENT_NAMES: tuple[str, ...] = (
    "Pelvis", "L5", "L3", "T12", "T8", "Neck", "Head",
    "RightShoulder", "RightUpperArm", "RightForeArm", "RightHand",
    "LeftShoulder", "LeftUpperArm", "LeftForeArm", "LeftHand",
    "RightUpperLeg", "RightLowerLeg", "RightFoot", "RightToe",
    "LeftUpperLeg", "LeftLowerLeg", "LeftFoot", "LeftToe",
)  # fmt: skip
#: segment ID (1-based) -> name
SEGMENTS: dict[int, str] = {i + 1: n for i, n in enumerate(SEGMENT_NAMES)}
#: canonical bone -> MVN segment whose origin is that joint
BONE_SEGMENTS: dict[str, str] = {
    "pelvis": "Pelvis",
    "spine": "L3",
    "chest": "T8",
    "neck": "Neck",
    "head": "Head",
    **{
        f"{side}_{bone}": f"{S}{seg}"
        for side, S in (("left", "Left"), ("right", "Right"))
        for bone, seg in (("clavicle", "Shoulder"), ("shoulder", "UpperArm"), ("elbow", "ForeArm"), ("wrist", "Hand"))
    },
}


class MvnError(ValueError):
    """A datagram that is not a valid MVN type-02 pose datagram.

    Attributes:
        reason: short tag counted in ServiceStatus.
    """

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class MvnHeader:
    """Decoded datagram header (fields as in the specification)."""

    message_type: str
    sample_counter: int
    datagram_counter: int
    last: bool
    n_items: int
    time_code_ms: int
    character_id: int
    n_body_segments: int
    n_props: int
    n_finger_segments: int
    payload_size: int


def parse_datagram(data: bytes) -> tuple[MvnHeader, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """Decode one MXTP02 datagram.

    Returns:
        (header, segment ID -> (position (3,) [file units], quaternion (4,) wxyz)).

    Raises:
        MvnError: wrong magic, message type, sizes.
    """
    if len(data) < HEADER.size:
        raise MvnError("mvn_short", f"{len(data)} bytes, header alone is {HEADER.size}")
    ident, sample, dgc, n_items, tc, char, nb, npr, nf, _res, size = HEADER.unpack_from(data)
    if ident[:4] != b"MXTP":
        raise MvnError("mvn_magic", f"ID string {ident!r} does not start with MXTP")
    mtype = ident[4:6].decode("ascii", "replace")
    if mtype != "02":
        raise MvnError("mvn_type", f"message type {mtype!r}; only 02 (quaternion pose) is decoded")
    body = len(data) - HEADER.size
    if size != body or n_items * QUAT_ITEM.size > body:
        raise MvnError("mvn_size", f"payload size field {size}, {body} bytes present, {n_items} items of 32 declared")
    segs = {}
    for k in range(n_items):
        sid, x, y, z, qw, qx, qy, qz = QUAT_ITEM.unpack_from(data, HEADER.size + k * QUAT_ITEM.size)
        segs[sid] = (np.array([x, y, z], float), np.array([qw, qx, qy, qz], float))
    hdr = MvnHeader(mtype, sample, dgc & 0x7F, bool(dgc & 0x80), n_items, tc, char, nb, npr, nf, size)
    return hdr, segs


def build_datagrams(
    sample_counter: int,
    time_code_ms: int,
    segments: dict[int, tuple[np.ndarray, np.ndarray]],
    character_id: int = 0,
    max_items: int = 64,
) -> list[bytes]:
    """Encode a pose as MXTP02 datagram(s), splitting after ``max_items`` segments.

    Args:
        segments: segment ID -> (position (3,) [cm], quaternion (4,) wxyz).
    """
    ids = sorted(segments)
    chunks = [ids[i : i + max_items] for i in range(0, len(ids), max_items)] or [[]]
    out = []
    for k, chunk in enumerate(chunks):
        payload = b"".join(
            QUAT_ITEM.pack(sid, *map(float, segments[sid][0]), *map(float, segments[sid][1])) for sid in chunk
        )
        dgc = k | (0x80 if k == len(chunks) - 1 else 0)
        n_body = sum(1 for s in ids if s <= 23)
        hdr = HEADER.pack(
            b"MXTP02", sample_counter, dgc, len(chunk), time_code_ms, character_id, n_body, 0, 0, 0, len(payload)
        )
        out.append(hdr + payload)
    return out


@dataclass
class MvnDecoder:
    """Assemble datagrams into HumanFrames (pure; no sockets).

    Attributes:
        units: position unit of the stream ("cm" per the specification, or "m").
        character_id: only this character is decoded (None: any).
        source: HumanFrame source tag.
    """

    units: str = "cm"
    character_id: int | None = None
    source: str = "xsens"
    _parts: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.units not in UNIT_SCALES:
            raise ValueError(f"units {self.units!r}; choose one of {list(UNIT_SCALES)}")

    def step(self, data: bytes, t0_ns: int) -> HumanFrame | None:
        """Feed one datagram; return a frame when a sample is complete.

        Raises:
            MvnError: malformed datagram or no pelvis in the sample.
        """
        hdr, segs = parse_datagram(data)
        if self.character_id is not None and hdr.character_id != self.character_id:
            return None
        parts = self._parts.setdefault(hdr.sample_counter, {})
        parts.update(segs)
        if not hdr.last:
            if len(self._parts) > 8:  # a lost final datagram must not leak memory
                for key in sorted(self._parts)[:-8]:
                    del self._parts[key]
            return None
        parts = self._parts.pop(hdr.sample_counter)
        for key in [k for k in self._parts if k < hdr.sample_counter]:
            del self._parts[key]
        return self.to_frame(hdr, parts, t0_ns)

    def to_frame(self, hdr: MvnHeader, segs: dict[int, tuple[np.ndarray, np.ndarray]], t0_ns: int) -> HumanFrame:
        """Pose of one sample as a HumanFrame (bones in the Pelvis segment frame).

        Quaternions are passed through unnormalised and NaN kept, so the
        sanitizer sees (and counts) what the source sent.
        """
        by_name = {SEGMENTS[s]: v for s, v in segs.items() if s in SEGMENTS}
        if "Pelvis" not in by_name:
            raise MvnError("mvn_no_pelvis", f"sample {hdr.sample_counter}: no Pelvis segment (ID 1)")
        scale = UNIT_SCALES[self.units]
        p_root = by_name["Pelvis"][0] * scale
        q_root = by_name["Pelvis"][1]
        n_root = np.linalg.norm(q_root)
        R_root = quats_to_matrices(q_root) if np.all(np.isfinite(q_root)) and n_root > 1e-6 else np.full((3, 3), np.nan)
        bones = {}
        for bone, seg in BONE_SEGMENTS.items():
            if seg not in by_name:
                continue
            p, q = by_name[seg]
            if bone == "pelvis":
                bones[bone] = Bone(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), True)
                continue
            p_local = R_root.T @ (p * scale - p_root)
            nq = np.linalg.norm(q)
            if np.all(np.isfinite(q)) and nq > 1e-6 and np.all(np.isfinite(R_root)):
                q_local = matrices_to_quats(R_root.T @ quats_to_matrices(q)) * nq  # keep |q| for the sanitizer
            else:
                q_local = np.full(4, np.nan)
            bones[bone] = Bone(p_local, q_local, True)
        return HumanFrame(
            Header(hdr.sample_counter, hdr.time_code_ms / 1000.0, t0_ns), self.source, Pose(p_root, q_root), bones
        )
