"""Validation and repair of live HumanFrames (pure logic, no bus).

Live sources send what they send: NaN, missing bones, quaternions that are not
quite unit, repeated or late sequence numbers. :func:`decode_lenient` reads a
HumanFrame datagram without rejecting those (only unreadable payloads raise),
and :class:`FrameSanitizer` decides, frame by frame, what to repair and what
to drop. Every decision is returned as an :class:`Issue` so the node can count
it in ServiceStatus and log the first of each reason.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from shared.messages import (
    HUMAN_BONES,
    Bone,
    Header,
    HumanFrame,
    MessageError,
    Pose,
    unpack_message,
)
from shared.sequence import SequenceGuard

_IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True)
class Issue:
    """One problem found in a frame.

    Attributes:
        reason: short tag (``"duplicate_seq"``, ``"nan_bone"``, ...).
        action: "dropped" (whole frame), "invalidated" (bone flagged invalid or
            removed) or "repaired" (value fixed, frame kept).
        detail: human-readable text.
    """

    reason: str
    action: str
    detail: str


def _num_array(x, n: int) -> np.ndarray | None:
    """Float array of length n (NaN allowed), or None if the shape/types are wrong."""
    if not isinstance(x, (list, tuple)) or len(x) != n:
        return None
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in x):
        return None
    return np.asarray(x, dtype=float)


def decode_lenient(payload: bytes) -> tuple[HumanFrame, list[Issue]]:
    """Decode a HumanFrame datagram, keeping NaN and non-unit quaternions for the sanitizer.

    Bones with unknown names or malformed entries are left out and reported.

    Raises:
        MessageError: unreadable payload (not msgpack, wrong version/type, no header or root).
    """
    d = unpack_message(payload, HumanFrame.TYPE)  # the bus limits, version and type: as the strict decoder
    hdr = d.get("hdr")
    if not (isinstance(hdr, (list, tuple)) and len(hdr) == 3):
        raise MessageError("missing", "hdr must be [seq, stamp, t0]")
    seq, stamp, t0 = hdr
    if isinstance(seq, bool) or not isinstance(seq, int) or seq < 0:
        raise MessageError("type", f"hdr.seq must be a non-negative int, got {seq!r}")
    if isinstance(stamp, bool) or not isinstance(stamp, (int, float)):
        raise MessageError("type", f"hdr.stamp must be a number, got {type(stamp).__name__}")
    if isinstance(t0, bool) or not isinstance(t0, int):
        raise MessageError("type", f"hdr.t0 must be an int [ns], got {type(t0).__name__}")
    root = d.get("root")
    rp = _num_array(root[0], 3) if isinstance(root, (list, tuple)) and len(root) == 2 else None
    rq = _num_array(root[1], 4) if rp is not None else None
    if rp is None or rq is None:
        raise MessageError("missing", "root must be [[x, y, z], [w, x, y, z]]")
    names, ps, qs, valid = d.get("names"), d.get("p"), d.get("q"), d.get("valid")
    if not all(isinstance(v, (list, tuple)) for v in (names, ps, qs, valid)) or not (
        len(names) == len(ps) == len(qs) == len(valid)
    ):
        raise MessageError("shape", "names/p/q/valid must be lists of equal length")
    issues: list[Issue] = []
    bones: dict[str, Bone] = {}
    for n, p, q, ok in zip(names, ps, qs, valid):
        if not isinstance(n, str) or n not in HUMAN_BONES:
            issues.append(Issue("unknown_bone", "invalidated", f"bone {n!r} is not canonical; known: {HUMAN_BONES}"))
            continue
        if n in bones:
            issues.append(Issue("duplicate_bone", "invalidated", f"bone {n!r} sent twice; first kept"))
            continue
        pa, qa = _num_array(p, 3), _num_array(q, 4)
        if pa is None or qa is None or not isinstance(ok, bool):
            issues.append(Issue("malformed_bone", "invalidated", f"bone {n!r}: p (3,), q (4,), valid bool expected"))
            continue
        bones[n] = Bone(pa, qa, ok)
    src = d.get("src", "")
    oriented = d.get("ori", True)
    if not isinstance(oriented, bool):
        issues.append(Issue("malformed_ori", "repaired", f"ori must be a bool, got {oriented!r}: taken as true"))
        oriented = True
    frame = HumanFrame(
        Header(seq, float(stamp), t0), src if isinstance(src, str) else "", Pose(rp, rq), bones, oriented
    )
    return frame, issues


@dataclass
class FrameSanitizer:
    """Repair or drop live HumanFrames.

    Rules:
        * order (:class:`shared.sequence.SequenceGuard`, the rule retarget applies too):
          ``seq`` equal to the last accepted one -> dropped ("duplicate_seq"); lower ->
          dropped ("seq_backwards"), a stamp not after the last -> dropped ("time_backwards"),
          unless it is more than ``reset_gap`` lower or ``resync_after`` frames in a row were
          out of order, which is taken as a restarted source ("seq_reset", repaired).
        * non-finite ``stamp`` or root position -> dropped ("nan_root"), before the order check.
        * quaternion norm within ``quat_repair_tol`` of 1 -> normalised
          ("quat_normalised"); further off (or NaN) -> root: dropped
          ("bad_root_quaternion"); bone: flagged invalid ("bad_quaternion").
        * bone position NaN/inf or farther than ``max_bone_distance`` from the
          pelvis -> flagged invalid with its last good position ("nan_bone",
          "bone_out_of_range"), removed if it never had one.
        * a bone seen before and now absent -> reported ("missing_bone"), not invented.
        * no valid bone left -> dropped ("empty").

    Attributes:
        quat_repair_tol: largest | |q| - 1 | repaired by normalisation.
        max_bone_distance: [m] from the pelvis origin.
        reset_gap: seq jump back treated as a source restart at once.
        resync_after: consecutive out-of-order frames treated as a source restart.
        trust_t0: ``hdr.t0`` is the sender's wall clock when it made the frame, so a lower seq with
            a later t0 is a restart at once (False when t0 is stamped on arrival).
        counts: (reason, action) -> count over the sanitizer's life.
    """

    quat_repair_tol: float = 0.1
    max_bone_distance: float = 3.0
    reset_gap: int = 1000
    resync_after: int = 30
    trust_t0: bool = True
    counts: Counter = field(default_factory=Counter)
    _last_p: dict[str, np.ndarray] = field(default_factory=dict)
    _last_q: dict[str, np.ndarray] = field(default_factory=dict)
    _seen: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        self._guard = SequenceGuard(self.reset_gap, self.resync_after, self.trust_t0)

    def _quat(self, q: np.ndarray) -> tuple[np.ndarray | None, bool]:
        """(unit quaternion or None if beyond repair, was_repaired)."""
        if not np.all(np.isfinite(q)):
            return None, False
        n = float(np.linalg.norm(q))
        if abs(n - 1.0) <= 1e-6:
            return q, False
        if abs(n - 1.0) <= self.quat_repair_tol:
            return q / n, True
        return None, False

    def step(self, frame: HumanFrame, issues: list[Issue] | None = None) -> tuple[HumanFrame | None, list[Issue]]:
        """Check one frame.

        Args:
            frame: decoded frame (possibly with NaN, non-unit quaternions).
            issues: issues already found while decoding (kept in the output).

        Returns:
            (frame to publish or None if dropped, every issue found).
        """
        out = list(issues or [])
        result = self._step(frame, out)
        for i in out:
            self.counts[(i.reason, i.action)] += 1
        return result, out

    def _step(self, f: HumanFrame, out: list[Issue]) -> HumanFrame | None:
        seq = f.hdr.seq
        if not math.isfinite(f.hdr.stamp) or not np.all(np.isfinite(f.root.p)):
            out.append(Issue("nan_root", "dropped", f"seq {seq}: non-finite stamp or root position"))
            return None
        verdict = self._guard.check(f.hdr, f.source)
        if not verdict.ok:
            out.append(Issue(verdict.reason, "dropped", verdict.detail))
            return None
        if verdict.restarted:
            out.append(Issue("seq_reset", "repaired", verdict.detail))
        rq, fixed = self._quat(np.asarray(f.root.q, float))
        if rq is None:
            out.append(Issue("bad_root_quaternion", "dropped", f"seq {seq}: root quaternion {np.round(f.root.q, 4)}"))
            return None
        if fixed:
            out.append(Issue("quat_normalised", "repaired", f"seq {seq}: root quaternion renormalised"))
        bones: dict[str, Bone] = {}
        for name, b in f.bones.items():
            p, q, ok = np.asarray(b.p, float), np.asarray(b.q, float), bool(b.valid)
            if not np.all(np.isfinite(p)):
                out.append(Issue("nan_bone", "invalidated", f"seq {seq}: {name} position not finite"))
                p, ok = self._last_p.get(name), False
            elif np.linalg.norm(p) > self.max_bone_distance:
                out.append(
                    Issue("bone_out_of_range", "invalidated", f"seq {seq}: {name} {np.linalg.norm(p):.2f} m away")
                )
                p, ok = self._last_p.get(name), False
            qq, fixed = self._quat(q)
            if qq is None:
                out.append(Issue("bad_quaternion", "invalidated", f"seq {seq}: {name} quaternion {np.round(q, 4)}"))
                qq, ok = self._last_q.get(name, _IDENTITY_Q), False
            elif fixed:
                out.append(Issue("quat_normalised", "repaired", f"seq {seq}: {name} quaternion renormalised"))
            if p is None:
                continue  # never had a good position: nothing honest to send
            bones[name] = Bone(p, qq, ok)
            if ok:
                self._last_p[name], self._last_q[name] = p, qq
        missing = sorted(self._seen - set(f.bones))
        if missing:
            out.append(Issue("missing_bone", "invalidated", f"seq {seq}: bones absent {missing}"))
        self._seen |= set(f.bones)
        if not any(b.valid for b in bones.values()):
            out.append(Issue("empty", "dropped", f"seq {seq}: no valid bone"))
            return None
        self._guard.accept(f.hdr, f.source)
        return HumanFrame(f.hdr, f.source, Pose(np.asarray(f.root.p, float), rq), bones, f.oriented)
