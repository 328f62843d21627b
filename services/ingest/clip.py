"""The :class:`Clip`: a recorded motion in canonical bones, and :func:`load_clip`.

Frames and conventions (shared by every reader):

* **World**: Z-up, right-handed, metres. Y-up sources are rotated with
  :data:`~services.ingest.rotations.Y_UP_TO_Z_UP` (source +Z forward -> x,
  source +X -> y, source +Y up -> z).
* **Pelvis (root) frame**: origin at the pelvis joint, x forward, y left,
  z up for the operator, rigidly attached to the pelvis (same axes as the
  robot's pelvis frame). ``root_p``/``root_q`` give it in the world.
* **Bones**: ``positions[b]`` is the joint centre in the pelvis frame
  (``T_h^w = (T_w^h)^-1 T_w^e``, seed 000 section 1.2): shoulder = gleno-humeral
  joint, elbow = elbow joint centre, wrist = wrist joint centre, hand = hand tip.
  ``quats[b]`` is the orientation of the rig's own joint frame (BVH: the joint's
  frame after its channel rotations) expressed in the pelvis frame; its axes are
  rig-specific, so use it relative to a reference pose. ``pelvis`` is the pelvis
  frame itself (zero position, identity quaternion). C3D clips carry no bone
  orientation: quaternions are identity and ``has_orientation`` is False.
* ``valid[b]`` is False where the bone is unknown (occluded markers); the
  position is NaN there, never zero.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from services.ingest.errors import ClipError
from services.ingest.rotations import matrices_to_quats, quats_to_matrices
from shared.messages import HUMAN_BONES, Bone, Header, HumanFrame, Pose

__all__ = ["Clip", "ClipError", "clip_from_file", "clip_from_world", "load_clip"]

_IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


def _hold(a: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Forward-fill rows where ``ok`` is False (leading gaps take the first valid row)."""
    idx = np.where(ok, np.arange(len(ok)), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.argmax(ok))
    idx[idx < 0] = first
    return a[idx]


@dataclass
class Clip:
    """A motion clip in canonical bones.

    Attributes:
        name: clip name (file stem).
        fps: frame rate [Hz].
        times: (T,) clip time of each frame [s], starting at 0.
        positions: bone -> (T, 3) joint centre in the pelvis frame [m] (NaN where invalid).
        quats: bone -> (T, 4) wxyz orientation in the pelvis frame (identity when unknown).
        valid: bone -> (T,) bool.
        root_p: (T, 3) pelvis origin in the Z-up world [m].
        root_q: (T, 4) wxyz pelvis orientation in the Z-up world.
        source: source tag put in each HumanFrame (``"bvh:<file>"``, ``"c3d:<file>"``).
        has_orientation: False when ``quats`` are placeholders (C3D).
        meta: reader details (skeleton map, units, up axis, file path, ...).
    """

    name: str
    fps: float
    times: np.ndarray
    positions: dict[str, np.ndarray]
    quats: dict[str, np.ndarray]
    valid: dict[str, np.ndarray]
    root_p: np.ndarray
    root_q: np.ndarray
    source: str = ""
    has_orientation: bool = True
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._held: dict[str, np.ndarray] = {}
        for b in self.positions:
            ok = self.valid[b]
            if ok.any():
                self._held[b] = _hold(self.positions[b], ok)
        root_ok = np.all(np.isfinite(self.root_p), axis=1) & np.all(np.isfinite(self.root_q), axis=1)
        self._root_p = _hold(self.root_p, root_ok) if root_ok.any() else np.zeros_like(self.root_p)
        self._root_q = _hold(self.root_q, root_ok) if root_ok.any() else np.tile(_IDENTITY_Q, (len(self.times), 1))

    @property
    def n_frames(self) -> int:
        return len(self.times)

    @property
    def duration(self) -> float:
        """Time of the last frame [s]."""
        return float(self.times[-1]) if len(self.times) else 0.0

    @property
    def bones(self) -> list[str]:
        """Canonical bones present in the clip (in ``HUMAN_BONES`` order)."""
        return [b for b in HUMAN_BONES if b in self.positions]

    def frame(self, i: int, seq: int, t0_ns: int | None = None) -> HumanFrame:
        """HumanFrame of frame ``i``.

        Bones never valid in the whole clip are left out; a bone invalid at
        frame ``i`` is sent with ``valid=False`` and its last valid position
        (the wire format needs finite numbers).

        Args:
            i: frame index in [0, n_frames).
            seq: header sequence number.
            t0_ns: wall-clock time the frame enters the bus [ns]; now when None.
        """
        bones = {}
        for b, held in self._held.items():
            bones[b] = Bone(held[i].copy(), self.quats[b][i].copy(), bool(self.valid[b][i]))
        hdr = Header(seq, float(self.times[i]), time.time_ns() if t0_ns is None else t0_ns)
        root = Pose(self._root_p[i].copy(), self._root_q[i].copy())
        return HumanFrame(hdr, self.source, root, bones, self.has_orientation)

    def slice(self, start: float | None = None, end: float | None = None) -> Clip:
        """Frames with ``start <= t <= end`` [s]; times restart at 0."""
        lo = 0 if start is None else int(np.searchsorted(self.times, start - 1e-9))
        hi = len(self.times) if end is None else int(np.searchsorted(self.times, end + 1e-9, side="right"))
        if hi <= lo:
            raise ClipError(f"{self.name}: no frames between {start} s and {end} s (clip lasts {self.duration:.3f} s)")
        s = np.s_[lo:hi]
        return replace(
            self,
            times=self.times[s] - self.times[lo],
            positions={b: v[s] for b, v in self.positions.items()},
            quats={b: v[s] for b, v in self.quats.items()},
            valid={b: v[s] for b, v in self.valid.items()},
            root_p=self.root_p[s],
            root_q=self.root_q[s],
        )

    def world_positions(self, bone: str) -> np.ndarray:
        """(T, 3) bone position back in the Z-up world [m]."""
        R = quats_to_matrices(self.root_q)
        return np.einsum("tij,tj->ti", R, self.positions[bone]) + self.root_p


def clip_from_world(
    name: str,
    fps: float,
    world_p: dict[str, np.ndarray],
    root_p: np.ndarray,
    root_R: np.ndarray,
    world_R: dict[str, np.ndarray] | None = None,
    source: str = "",
    meta: dict[str, Any] | None = None,
) -> Clip:
    """Express world-frame joints in the pelvis frame and build a :class:`Clip`.

    Args:
        world_p: bone -> (T, 3) joint centre in the Z-up world [m]; NaN rows are invalid.
        root_p: (T, 3) pelvis origin in the world [m] (NaN where unknown).
        root_R: (T, 3, 3) pelvis axes (x forward, y left, z up) in the world.
        world_R: bone -> (T, 3, 3) joint frame in the world, or None (no orientation).
    """
    T = len(root_p)
    Rt = np.swapaxes(root_R, 1, 2)
    positions, quats, valid = {}, {}, {}
    root_ok = np.all(np.isfinite(root_p), axis=1) & np.all(np.isfinite(root_R), axis=(1, 2))
    for b in HUMAN_BONES:
        if b == "pelvis":
            positions[b] = np.where(root_ok[:, None], np.zeros((T, 3)), np.nan)
            quats[b] = np.tile(_IDENTITY_Q, (T, 1))
            valid[b] = root_ok.copy()
            continue
        if b not in world_p:
            continue
        p = np.einsum("tij,tj->ti", Rt, world_p[b] - root_p)
        ok = np.all(np.isfinite(p), axis=1)
        p[~ok] = np.nan
        positions[b], valid[b] = p, ok
        if world_R is not None and b in world_R:
            Rl = Rt @ world_R[b]
            good = np.all(np.isfinite(Rl), axis=(1, 2))
            q = np.tile(_IDENTITY_Q, (T, 1))
            if good.any():
                q[good] = matrices_to_quats(Rl[good])
            quats[b] = q
        else:
            quats[b] = np.tile(_IDENTITY_Q, (T, 1))
    root_q = np.tile(_IDENTITY_Q, (T, 1))
    if root_ok.any():
        root_q[root_ok] = matrices_to_quats(root_R[root_ok])
    root_q[~root_ok] = np.nan
    return Clip(
        name=name,
        fps=float(fps),
        times=np.arange(T) / float(fps),
        positions=positions,
        quats=quats,
        valid=valid,
        root_p=np.where(root_ok[:, None], root_p, np.nan),
        root_q=root_q,
        source=source,
        has_orientation=world_R is not None,
        meta=dict(meta or {}),
    )


def clip_from_file(
    path: Path,
    fmt: str,
    fps: float,
    world_p: dict[str, np.ndarray],
    root_p: np.ndarray,
    root_R: np.ndarray,
    world_R: dict[str, np.ndarray] | None,
    t_start: float,
    meta: dict[str, Any],
) -> Clip:
    """:func:`clip_from_world` for a file reader: the clip is named after the file, its source tag
    is ``"<fmt>:<file name>"`` and its meta holds the path, the format, the reader's ``meta`` and the
    read time since ``t_start`` (a :func:`time.perf_counter` value)."""
    return clip_from_world(
        path.stem,
        fps,
        world_p,
        root_p,
        root_R,
        world_R,
        source=f"{fmt}:{path.name}",
        meta={"path": str(path), "format": fmt, **meta, "parse_s": time.perf_counter() - t_start},
    )


def load_clip(path: str | Path, skeleton_map: Any = None, **opts: Any) -> Clip:
    """Load a motion file as a :class:`Clip`, dispatching on the extension.

    Args:
        path: ``.bvh`` or ``.c3d`` file.
        skeleton_map: BVH: a :class:`~services.ingest.skeleton_maps.SkeletonMap`
            or a map file path (auto-detected among the built-in maps when None).
            C3D: a :class:`~services.ingest.c3d.MarkerMap` or a marker-map file path.
        **opts: reader options; BVH: ``units`` ("auto", "m", "cm", "mm", "in"),
            ``up`` ("auto", "y", "z"), ``position_mode`` ("auto", "replace", "add");
            C3D: ``prefix`` (subject prefix, e.g. "Daphnee:").

    Raises:
        ClipError: unreadable file, unknown rig, bad options (clear text, never a crash).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        from services.ingest.bvh import read_bvh_clip

        return read_bvh_clip(path, skeleton_map=skeleton_map, **opts)
    if suffix == ".c3d":
        from services.ingest.c3d import read_c3d_clip

        return read_c3d_clip(path, marker_map=skeleton_map, **opts)
    raise ClipError(f"{path}: unsupported file type '{suffix}' (supported: .bvh, .c3d)")
