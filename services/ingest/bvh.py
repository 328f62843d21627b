"""BVH reading (any channel order, 3 or 6 channels, any rate/units/up axis) and writing.

:func:`parse_bvh` gives the raw :class:`BvhData` (hierarchy + channel matrix),
:meth:`BvhData.forward_kinematics` the joint frames in the file's own world,
:func:`read_bvh_clip` the canonical :class:`~services.ingest.clip.Clip`
(conventions in :mod:`services.ingest.clip`), and :func:`write_bvh` writes a
:class:`BvhData` back out.

Position channels on non-root joints: most tools add them to the OFFSET, but
some (the Bandai Namco dataset) store the full local translation there (the
channel values equal the OFFSET). ``position_mode="auto"`` picks "replace"
when the non-root position channels of the first frame equal the offsets,
else "add".
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from services.ingest.body_frame import arm_length, left_axis, trunk_top, unit_scale, up_axis
from services.ingest.clip import Clip, clip_from_file
from services.ingest.errors import BvhError, ClipError
from services.ingest.rotations import euler_to_matrix, frame_from_axes
from services.ingest.skeleton_maps import SkeletonMap, detect_map, load_skeleton_map

log = logging.getLogger(__name__)

_AXES = "XYZ"


@dataclass
class BvhJoint:
    """One joint of the hierarchy.

    Attributes:
        name: joint name. parent: index of the parent joint (-1 for the root).
        offset: (3,) rest translation from the parent [file units].
        channels: channel names in file order (``"Xposition"``, ``"Zrotation"``, ...).
        end_site: (3,) End Site offset [file units], or None.
        first_channel: column of the first channel in the motion matrix.
    """

    name: str
    parent: int
    offset: np.ndarray
    channels: list[str] = field(default_factory=list)
    end_site: np.ndarray | None = None
    first_channel: int = 0


@dataclass
class BvhData:
    """A parsed BVH file.

    Attributes:
        joints: joints in file (topological) order.
        frame_time: [s] per frame.
        motion: (T, n_channels) channel values (positions in file units, angles [deg]).
    """

    joints: list[BvhJoint]
    frame_time: float
    motion: np.ndarray

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def n_channels(self) -> int:
        return sum(len(j.channels) for j in self.joints)

    def index(self, name: str) -> int:
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise KeyError(name)

    def detect_position_mode(self) -> str:
        """ "replace" if non-root position channels hold the offsets (Bandai quirk), else "add"."""
        votes = []
        for j in self.joints[1:]:
            cols = [j.first_channel + k for k, c in enumerate(j.channels) if c.lower().endswith("position")]
            if len(cols) == 3 and len(self.motion):
                tol = 1e-3 * max(1.0, float(np.abs(j.offset).max()))
                votes.append(bool(np.all(np.abs(self.motion[0, cols] - j.offset) <= tol)) and np.any(j.offset != 0))
        return "replace" if votes and sum(votes) * 2 > len(votes) else "add"

    def forward_kinematics(self, position_mode: str = "auto") -> tuple[np.ndarray, np.ndarray]:
        """Global joint frames in the file's world.

        Args:
            position_mode: "add" (translation = offset + position channels),
                "replace" (translation = position channels) or "auto".

        Returns:
            R (T, J, 3, 3) joint orientation and p (T, J, 3) joint origin [file units].
        """
        if position_mode == "auto":
            position_mode = self.detect_position_mode()
        if position_mode not in ("add", "replace"):
            raise ClipError(f"position_mode {position_mode!r}; choose auto, add or replace")
        T, J = len(self.motion), len(self.joints)
        R = np.empty((T, J, 3, 3))
        p = np.empty((T, J, 3))
        for ji, j in enumerate(self.joints):
            t_local = np.tile(j.offset, (T, 1))
            rot_cols, rot_order = [], ""
            for k, c in enumerate(j.channels):
                col, axis, kind = j.first_channel + k, _AXES.index(c[0].upper()), c[1:].lower()
                if kind == "position":
                    vals = self.motion[:, col]
                    t_local[:, axis] = vals if position_mode == "replace" else t_local[:, axis] + vals
                else:
                    rot_cols.append(col)
                    rot_order += c[0].upper()
            R_local = (
                euler_to_matrix(rot_order, self.motion[:, rot_cols]) if rot_cols else np.tile(np.eye(3), (T, 1, 1))
            )
            if j.parent < 0:
                R[:, ji], p[:, ji] = R_local, t_local
            else:
                Rp = R[:, j.parent]
                R[:, ji] = Rp @ R_local
                p[:, ji] = p[:, j.parent] + np.einsum("tij,tj->ti", Rp, t_local)
        return R, p


# --------------------------------------------------------------------------- parsing


def _tokens(lines: list[str], start: int, stop: int):
    for ln in range(start, stop):
        for tok in lines[ln].replace("{", " { ").replace("}", " } ").split():
            yield tok, ln + 1


class _Hierarchy:
    """Reader of the HIERARCHY section: tokens with their line numbers, joints in file order."""

    def __init__(self, path: Path, lines: list[str], motion_line: int) -> None:
        self.path, self.motion_line = path, motion_line
        self.toks = list(_tokens(lines, 0, motion_line))
        self.pos = 0
        self.joints: list[BvhJoint] = []
        self.n_chan = 0
        self.stack: list[int] = []  # open joints

    def err(self, msg: str, ln: int | None = None) -> BvhError:
        if ln is None:
            ln = self.toks[self.pos][1] if self.pos < len(self.toks) else self.motion_line + 1
        return BvhError(f"{self.path}:{ln}: {msg}")

    def nxt(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.toks):
            raise self.err(f"unexpected end of HIERARCHY, expected {what}")
        tok = self.toks[self.pos]
        self.pos += 1
        return tok

    def keyword(self, word: str, context: str = "", hint: str = "") -> int:
        """Consume ``word`` (any case); returns its line."""
        tok, ln = self.nxt(word)
        if tok.upper() != word:
            raise self.err(f"{context}expected {word}, got {tok!r}{hint}", ln)
        return ln

    def numbers(self, n: int, what: str) -> np.ndarray:
        vals = []
        for _ in range(n):
            tok, ln = self.nxt(what)
            try:
                vals.append(float(tok))
            except ValueError:
                raise self.err(f"{what}: expected a number, got {tok!r}", ln) from None
        return np.asarray(vals)

    def parse(self) -> list[BvhJoint]:
        """All joints, with their channels and End Sites."""
        self.keyword("HIERARCHY", hint=" (not a BVH file?)")
        self.keyword("ROOT")
        kind: str | None = "ROOT"
        while kind is not None:
            if kind == "END":
                self.end_site()
            else:
                self.joint(kind)
            kind = self.next_block()
        if self.n_chan == 0:
            raise BvhError(f"{self.path}: the hierarchy has no channels")
        return self.joints

    def joint(self, kind: str) -> None:
        """``NAME { OFFSET x y z CHANNELS n ...``: the joint is opened (its children follow)."""
        name, ln = self.nxt("joint name")
        if name == "{":
            raise self.err(f"{kind} without a name", ln)
        # A name runs to the end of its line: 3ds Max Biped rigs name joints "Bip01 L UpperArm".
        while self.pos < len(self.toks) and self.toks[self.pos][1] == ln and self.toks[self.pos][0] != "{":
            name = f"{name} {self.nxt('joint name')[0]}"
        if name in (j.name for j in self.joints):
            raise self.err(f"duplicated joint name {name!r}", ln)
        if self.nxt("{")[0] != "{":
            raise self.err(f"expected '{{' after {kind} {name}", ln)
        parent = self.stack[-1] if self.stack else -1
        self.keyword("OFFSET", f"joint {name}: ")
        off = self.numbers(3, f"joint {name} OFFSET")
        self.keyword("CHANNELS", f"joint {name}: ")
        chans = self.channels(name)
        self.joints.append(BvhJoint(name, parent, off, chans, None, self.n_chan))
        self.n_chan += len(chans)
        self.stack.append(len(self.joints) - 1)

    def channels(self, joint: str) -> list[str]:
        cnt_tok, ln = self.nxt("channel count")
        if not cnt_tok.isdigit() or not 0 <= int(cnt_tok) <= 9:
            raise self.err(f"joint {joint}: bad channel count {cnt_tok!r}", ln)
        chans = []
        for _ in range(int(cnt_tok)):
            c, ln = self.nxt("channel name")
            if len(c) < 2 or c[0].upper() not in _AXES or c[1:].lower() not in ("position", "rotation"):
                raise self.err(f"joint {joint}: unknown channel {c!r} (expected [XYZ]position or [XYZ]rotation)", ln)
            chans.append(c)
        for kind in ("position", "rotation"):
            axes = [c[0].upper() for c in chans if c[1:].lower() == kind]
            if len(set(axes)) != len(axes):  # an Euler order like XXY has no rotation (nor a position two x's)
                raise self.err(f"joint {joint}: repeated {kind} axis in channels {' '.join(chans)}", ln)
        return chans

    def end_site(self) -> None:
        """``Site { OFFSET x y z }`` of the innermost open joint."""
        site, ln = self.nxt("Site")
        if site.lower() != "site" or self.nxt("{")[0] != "{":
            raise self.err("expected 'End Site {'", ln)
        self.keyword("OFFSET", "End Site: ")
        self.joints[self.stack[-1]].end_site = self.numbers(3, "End Site OFFSET")
        if self.nxt("}")[0] != "}":
            raise self.err("expected '}' closing End Site")

    def next_block(self) -> str | None:
        """Close joints up to the next ``JOINT`` or ``End`` (returned), or None at the end of the hierarchy."""
        while self.pos < len(self.toks):
            tok, ln = self.nxt("JOINT, End Site or '}'")
            word = tok.upper()
            if tok == "}":
                if not self.stack:
                    raise self.err("unbalanced '}'", ln)
                self.stack.pop()
            elif word in ("JOINT", "END"):
                if not self.stack:
                    raise self.err(f"{tok} after the root joint was closed", ln)
                return word
            elif word == "ROOT":
                raise self.err("several ROOT joints are not supported", ln)
            else:
                raise self.err(f"expected JOINT, End Site or '}}', got {tok!r}", ln)
        if self.stack:
            name = self.joints[self.stack[-1]].name
            raise self.err(f"unexpected end of HIERARCHY: {len(self.stack)} unclosed '{{' (joint {name})")
        return None


def _motion_header(path: Path, lines: list[str], motion_line: int) -> tuple[int, float, int]:
    """``Frames:`` and ``Frame Time:`` after the MOTION line; returns (frames, frame time [s], next line)."""
    frames = frame_time = None
    ln = motion_line + 1
    while ln < len(lines) and (frames is None or frame_time is None):
        s = lines[ln].strip()
        low = s.lower()
        try:
            if low.startswith("frames:"):
                frames = int(s.split(":", 1)[1])
            elif low.startswith("frame time:"):
                frame_time = float(s.split(":", 1)[1])
            elif s:
                raise BvhError(f"{path}:{ln + 1}: expected 'Frames:' and 'Frame Time:' after MOTION, got {s[:40]!r}")
        except ValueError:
            raise BvhError(f"{path}:{ln + 1}: bad MOTION header line {s[:40]!r}") from None
        ln += 1
    if frames is None or frame_time is None:
        raise BvhError(f"{path}: MOTION section lacks 'Frames:' or 'Frame Time:'")
    if not (frame_time > 0 and np.isfinite(frame_time)):
        raise BvhError(f"{path}: Frame Time must be > 0, got {frame_time}")
    return frames, frame_time, ln


def _motion_matrix(path: Path, lines: list[str], start: int, n_chan: int) -> np.ndarray:
    """(T, n_chan) channel values of the non-empty lines from ``start``; errors name the bad line."""
    data_lines = [(i, s) for i in range(start, len(lines)) if (s := lines[i].strip())]
    try:
        flat = np.array(" ".join(s for _, s in data_lines).split(), dtype=np.float64)
        ok = flat.size == len(data_lines) * n_chan
    except ValueError:
        ok = False
    if not ok:
        _raise_bad_row(path, data_lines, n_chan)
    motion = flat.reshape(len(data_lines), n_chan)
    if not np.all(np.isfinite(motion)):
        bad = int(np.argmax(~np.all(np.isfinite(motion), axis=1)))
        raise BvhError(f"{path}:{data_lines[bad][0] + 1}: frame {bad} contains NaN or inf")
    if len(motion) == 0:
        raise BvhError(f"{path}: no frames in MOTION")
    return motion


def _raise_bad_row(path: Path, data_lines: list[tuple[int, str]], n_chan: int) -> None:
    """Raise for the first frame line with a wrong value count or a value that is not a number."""
    for k, (i, s) in enumerate(data_lines):
        parts = s.split()
        if len(parts) != n_chan:
            raise BvhError(f"{path}:{i + 1}: frame {k} has {len(parts)} values, the hierarchy declares {n_chan}")
        for p_ in parts:
            try:
                float(p_)
            except ValueError:
                raise BvhError(f"{path}:{i + 1}: not a number: {p_!r}") from None


def parse_bvh(path: str | Path) -> BvhData:
    """Parse a BVH file.

    Raises:
        BvhError: with the file name and line number of the first problem.
    """
    path = Path(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise BvhError(f"{path}: cannot read ({exc.strerror})") from None
    lines = text.splitlines()
    motion_line = next((i for i, ln in enumerate(lines) if ln.strip().upper().startswith("MOTION")), None)
    if motion_line is None:
        raise BvhError(f"{path}: no MOTION section (truncated or not a BVH file)")
    hierarchy = _Hierarchy(path, lines, motion_line)
    joints = hierarchy.parse()
    frames, frame_time, first = _motion_header(path, lines, motion_line)
    motion = _motion_matrix(path, lines, first, hierarchy.n_chan)
    if len(motion) != frames:
        log.warning("%s: header says %d frames, file holds %d; using %d", path, frames, len(motion), len(motion))
    return BvhData(joints, frame_time, motion)


# --------------------------------------------------------------------------- clip


def _fps(frame_time: float) -> float:
    fps = 1.0 / frame_time
    return float(round(fps)) if abs(fps - round(fps)) < 1e-3 * fps else fps


def read_bvh_clip(
    path: str | Path,
    skeleton_map: SkeletonMap | str | Path | None = None,
    units: str = "auto",
    up: str = "auto",
    position_mode: str = "auto",
) -> Clip:
    """Read a BVH file as a canonical :class:`Clip`.

    Args:
        path: BVH file.
        skeleton_map: a map, a map file (TOML/JSON), or None to auto-detect.
        units: file length unit ("m", "cm", "mm", "in") or "auto" (from the arm length).
        up: file up axis ("y", "z") or "auto" (from the pelvis -> head direction).
        position_mode: see :meth:`BvhData.forward_kinematics`.

    Raises:
        ClipError: malformed file, unknown rig, unsupported axes.
    """
    t_start = time.perf_counter()
    path = Path(path)
    data = parse_bvh(path)
    smap, bones, hips = _resolve_rig(data, skeleton_map, path)
    if position_mode == "auto":
        position_mode = data.detect_position_mode()
    R, p = data.forward_kinematics(position_mode)
    src_p, src_R = _bone_frames(data, bones, R, p)
    units, scale = unit_scale(units, arm_length(src_p))
    top = trunk_top(src_p)
    up, A = up_axis(up, src_p[top] - src_p["pelvis"] if top else None, str(path))
    hip_p = {side: p[:, data.index(joint)] for side, joint in hips.items()}
    C, pelvis_from = _pelvis_offset(src_p, src_R, hip_p, top, A, path)
    world_p = {b: scale * np.einsum("ij,tj->ti", A, v) for b, v in src_p.items()}
    world_R = {b: A @ v for b, v in src_R.items()}
    meta = {
        "skeleton_map": smap.name,
        "joints": dict(bones),
        "units": units,
        "up": up,
        "position_mode": position_mode,
        "pelvis_frame_from": pelvis_from,
    }
    fps = _fps(data.frame_time)
    return clip_from_file(path, "bvh", fps, world_p, world_p["pelvis"], world_R["pelvis"] @ C, world_R, t_start, meta)


def _resolve_rig(
    data: BvhData, skeleton_map: SkeletonMap | str | Path | None, path: Path
) -> tuple[SkeletonMap, dict[str, str], dict[str, str]]:
    """The skeleton map (given or detected), canonical bone -> joint spec, and hip side -> joint."""
    names = data.names
    # a zero-length End Site (some Bandai files) carries no hand-tip information
    end_sites = {j.name for j in data.joints if j.end_site is not None and np.linalg.norm(j.end_site) > 0}
    if skeleton_map is None:
        return detect_map(names, end_sites, str(path))
    smap = skeleton_map if isinstance(skeleton_map, SkeletonMap) else load_skeleton_map(skeleton_map)
    bones, hips = smap.resolve(names, end_sites)
    detect_map(names, end_sites, str(path), maps=(smap,))  # raises with the full diagnosis if incomplete
    return smap, bones, hips


def _bone_frames(
    data: BvhData, bones: dict[str, str], R: np.ndarray, p: np.ndarray
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Canonical bone -> (T, 3) position and (T, 3, 3) frame in the file's world, from the joint frames
    R (T, J, 3, 3), p (T, J, 3); a spec ``"Joint/end"`` is the joint's End Site."""
    src_p, src_R = {}, {}
    for b, spec in bones.items():
        joint, _, tail = spec.partition("/")
        ji = data.index(joint)
        src_p[b] = p[:, ji] + R[:, ji] @ data.joints[ji].end_site if tail == "end" else p[:, ji]
        src_R[b] = R[:, ji]
    return src_p, src_R


def _pelvis_offset(
    src_p: dict[str, np.ndarray],
    src_R: dict[str, np.ndarray],
    hip_p: dict[str, np.ndarray],
    top: str | None,
    A: np.ndarray,
    path: Path,
) -> tuple[np.ndarray, str]:
    """Constant rotation C (3, 3) in the pelvis joint frame whose axes are the canonical pelvis frame.

    z is the mean pelvis -> ``top`` direction and y the mean right -> left hip (else shoulder)
    direction, both seen from the pelvis joint frame over the clip. Returns (C, "hips" or "shoulders").
    """
    Rpt = np.swapaxes(src_R["pelvis"], 1, 2)

    def mean_local(v: np.ndarray) -> np.ndarray:
        return np.mean(np.einsum("tij,tj->ti", Rpt, v), axis=0)

    if top:
        up_local = mean_local(src_p[top] - src_p["pelvis"])
    else:
        up_local = np.linalg.inv(A) @ np.array([0.0, 0.0, 1.0]) @ src_R["pelvis"][0]
    left, pelvis_from = left_axis(
        [
            ("hips", hip_p.get("left"), hip_p.get("right")),
            ("shoulders", src_p["left_shoulder"], src_p["right_shoulder"]),
        ]
    )
    C = frame_from_axes(up_local, mean_local(left))
    if not np.all(np.isfinite(C)):
        raise ClipError(f"{path}: cannot orient the pelvis frame (spine parallel to the hip axis)")
    return C, pelvis_from


# --------------------------------------------------------------------------- writing


def _fmt(v: float) -> str:
    s = f"{v:.9g}"
    return "0" if s == "-0" else s


def write_bvh(path: str | Path, data: BvhData) -> Path:
    """Write ``data`` as a BVH file (any channel layout the joints declare).

    Returns:
        The written path.
    """
    path = Path(path)
    children: dict[int, list[int]] = {}
    for i, j in enumerate(data.joints):
        children.setdefault(j.parent, []).append(i)
    if children.get(-1, []) != [0]:
        raise ClipError("write_bvh: exactly one root joint, first in the list, is required")
    if data.motion.shape[1] != data.n_channels:
        raise ClipError(f"write_bvh: motion has {data.motion.shape[1]} columns, joints declare {data.n_channels}")
    out = ["HIERARCHY"]

    def emit(i: int, depth: int) -> None:
        j, ind = data.joints[i], "  " * depth
        out.append(f"{ind}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}")
        out.append(f"{ind}{{")
        out.append(f"{ind}  OFFSET {' '.join(_fmt(v) for v in j.offset)}")
        out.append(f"{ind}  CHANNELS {len(j.channels)} {' '.join(j.channels)}".rstrip())
        for c in children.get(i, []):
            emit(c, depth + 1)
        if j.end_site is not None:
            out.extend(
                [
                    f"{ind}  End Site",
                    f"{ind}  {{",
                    f"{ind}    OFFSET {' '.join(_fmt(v) for v in j.end_site)}",
                    f"{ind}  }}",
                ]
            )
        out.append(f"{ind}}}")

    emit(0, 0)
    out += ["MOTION", f"Frames: {len(data.motion)}", f"Frame Time: {data.frame_time:.8f}"]
    out += [" ".join(_fmt(v) for v in row) for row in data.motion]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out) + "\n")
    return path
