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

from services.ingest.clip import Clip, clip_from_world
from services.ingest.errors import BvhError, ClipError
from services.ingest.rotations import Y_UP_TO_Z_UP, euler_to_matrix, frame_from_axes
from services.ingest.skeleton_maps import SkeletonMap, detect_map, load_skeleton_map

log = logging.getLogger(__name__)

_AXES = "XYZ"
#: Metres per file unit.
UNIT_SCALES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}


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
    toks = list(_tokens(lines, 0, motion_line))
    pos = 0

    def err(msg: str, ln: int | None = None) -> BvhError:
        if ln is None:
            ln = toks[pos][1] if pos < len(toks) else motion_line + 1
        return BvhError(f"{path}:{ln}: {msg}")

    def nxt(what: str) -> tuple[str, int]:
        nonlocal pos
        if pos >= len(toks):
            raise err(f"unexpected end of HIERARCHY, expected {what}")
        tok = toks[pos]
        pos += 1
        return tok

    def numbers(n: int, what: str) -> np.ndarray:
        vals = []
        for _ in range(n):
            tok, ln = nxt(what)
            try:
                vals.append(float(tok))
            except ValueError:
                raise err(f"{what}: expected a number, got {tok!r}", ln) from None
        return np.asarray(vals)

    tok, ln = nxt("HIERARCHY")
    if tok.upper() != "HIERARCHY":
        raise err(f"expected HIERARCHY, got {tok!r} (not a BVH file?)", ln)
    joints: list[BvhJoint] = []
    n_chan = 0
    stack: list[int] = []  # open joints; -2 marks an End Site block

    tok, ln = nxt("ROOT")
    if tok.upper() != "ROOT":
        raise err(f"expected ROOT, got {tok!r}", ln)
    kind = "ROOT"
    while True:
        if kind in ("ROOT", "JOINT"):
            name, ln = nxt("joint name")
            if name == "{":
                raise err(f"{kind} without a name", ln)
            if name in (j.name for j in joints):
                raise err(f"duplicated joint name {name!r}", ln)
            if nxt("{")[0] != "{":
                raise err(f"expected '{{' after {kind} {name}", ln)
            parent = stack[-1] if stack else -1
            tok, ln = nxt("OFFSET")
            if tok.upper() != "OFFSET":
                raise err(f"joint {name}: expected OFFSET, got {tok!r}", ln)
            off = numbers(3, f"joint {name} OFFSET")
            tok, ln = nxt("CHANNELS")
            if tok.upper() != "CHANNELS":
                raise err(f"joint {name}: expected CHANNELS, got {tok!r}", ln)
            cnt_tok, ln = nxt("channel count")
            if not cnt_tok.isdigit() or not 0 <= int(cnt_tok) <= 9:
                raise err(f"joint {name}: bad channel count {cnt_tok!r}", ln)
            chans = []
            for _ in range(int(cnt_tok)):
                c, ln = nxt("channel name")
                if len(c) < 2 or c[0].upper() not in _AXES or c[1:].lower() not in ("position", "rotation"):
                    raise err(f"joint {name}: unknown channel {c!r} (expected [XYZ]position or [XYZ]rotation)", ln)
                chans.append(c)
            joints.append(BvhJoint(name, parent, off, chans, None, n_chan))
            n_chan += len(chans)
            stack.append(len(joints) - 1)
        elif kind == "END":
            site, ln = nxt("Site")
            if site.lower() != "site" or nxt("{")[0] != "{":
                raise err("expected 'End Site {'", ln)
            tok, ln = nxt("OFFSET")
            if tok.upper() != "OFFSET":
                raise err(f"End Site: expected OFFSET, got {tok!r}", ln)
            if not stack or stack[-1] < 0:
                raise err("End Site outside a joint", ln)
            joints[stack[-1]].end_site = numbers(3, "End Site OFFSET")
            if nxt("}")[0] != "}":
                raise err("expected '}' closing End Site")
        # what follows: JOINT, End Site, or closing braces
        while True:
            if pos >= len(toks):
                if stack:
                    raise err(
                        f"unexpected end of HIERARCHY: {len(stack)} unclosed '{{' (joint {joints[stack[-1]].name})"
                    )
                break
            tok, ln = nxt("JOINT, End Site or '}'")
            if tok == "}":
                if not stack:
                    raise err("unbalanced '}'", ln)
                stack.pop()
                continue
            if tok.upper() in ("JOINT", "END") and not stack:
                raise err(f"{tok} after the root joint was closed", ln)
            if tok.upper() == "JOINT":
                kind = "JOINT"
            elif tok.upper() == "END":
                kind = "END"
            elif tok.upper() == "ROOT":
                raise err("several ROOT joints are not supported", ln)
            else:
                raise err(f"expected JOINT, End Site or '}}', got {tok!r}", ln)
            break
        if pos >= len(toks) and not stack:
            break
    if n_chan == 0:
        raise BvhError(f"{path}: the hierarchy has no channels")

    # MOTION header
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
    data_lines = [(i, s) for i in range(ln, len(lines)) if (s := lines[i].strip())]
    try:
        flat = np.array(" ".join(s for _, s in data_lines).split(), dtype=np.float64)
        ok = flat.size == len(data_lines) * n_chan
    except ValueError:
        ok = False
    if not ok:
        for k, (i, s) in enumerate(data_lines):
            parts = s.split()
            if len(parts) != n_chan:
                raise BvhError(f"{path}:{i + 1}: frame {k} has {len(parts)} values, the hierarchy declares {n_chan}")
            for p_ in parts:
                try:
                    float(p_)
                except ValueError:
                    raise BvhError(f"{path}:{i + 1}: not a number: {p_!r}") from None
    motion = flat.reshape(len(data_lines), n_chan)
    if not np.all(np.isfinite(motion)):
        bad = int(np.argmax(~np.all(np.isfinite(motion), axis=1)))
        raise BvhError(f"{path}:{data_lines[bad][0] + 1}: frame {bad} contains NaN or inf")
    if len(motion) == 0:
        raise BvhError(f"{path}: no frames in MOTION")
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
    names = data.names
    # a zero-length End Site (some Bandai files) carries no hand-tip information
    end_sites = {j.name for j in data.joints if j.end_site is not None and np.linalg.norm(j.end_site) > 0}
    if skeleton_map is None:
        smap, bones, hips = detect_map(names, end_sites, str(path))
    else:
        smap = skeleton_map if isinstance(skeleton_map, SkeletonMap) else load_skeleton_map(skeleton_map)
        bones, hips = smap.resolve(names, end_sites)
        detect_map(names, end_sites, str(path), maps=(smap,))  # raises with the full diagnosis if incomplete
    if position_mode == "auto":
        position_mode = data.detect_position_mode()
    R, p = data.forward_kinematics(position_mode)

    def point(spec: str) -> tuple[np.ndarray, np.ndarray]:
        joint, _, tail = spec.partition("/")
        ji = data.index(joint)
        if tail == "end":
            return p[:, ji] + R[:, ji] @ data.joints[ji].end_site, R[:, ji]
        return p[:, ji], R[:, ji]

    src_p = {b: point(s)[0] for b, s in bones.items()}
    src_R = {b: point(s)[1] for b, s in bones.items()}

    # units from the arm length (upper arm + forearm ~ 0.45-0.65 m for adults)
    arm = np.mean(
        [
            np.linalg.norm(src_p[f"{s}_shoulder"][0] - src_p[f"{s}_elbow"][0])
            + np.linalg.norm(src_p[f"{s}_elbow"][0] - src_p[f"{s}_wrist"][0])
            for s in ("left", "right")
        ]
    )
    if units == "auto":
        units = "m" if arm < 2.0 else "cm" if arm < 150.0 else "mm"
    if units not in UNIT_SCALES:
        raise ClipError(f"units {units!r}; choose auto or one of {list(UNIT_SCALES)}")
    scale = UNIT_SCALES[units]

    # up axis from the pelvis -> upper body direction, median over the clip
    top = next((b for b in ("head", "neck", "chest", "spine") if b in src_p), None)
    up_vec = np.median(src_p[top] - src_p["pelvis"], axis=0) if top else None
    if up == "auto":
        if up_vec is None:
            raise ClipError(f"{path}: cannot detect the up axis (no spine/neck/head mapped); pass up='y' or 'z'")
        k = int(np.argmax(np.abs(up_vec)))
        if k == 0 or up_vec[k] < 0:
            raise ClipError(
                f"{path}: the body points along {'-+'[up_vec[k] > 0]}{'XYZ'[k]}; only +Y or +Z up is supported"
            )
        up = "xyz"[k]
    if up not in ("y", "z"):
        raise ClipError(f"up {up!r}; choose auto, y or z")
    A = Y_UP_TO_Z_UP if up == "y" else np.eye(3)

    world_p = {b: scale * np.einsum("ij,tj->ti", A, v) for b, v in src_p.items()}
    world_R = {b: A @ v for b, v in src_R.items()}

    # Pelvis frame: constant rotation C in the pelvis joint frame, from the
    # average spine direction (z) and right -> left hip direction (y).
    Rp, pp = src_R["pelvis"], src_p["pelvis"]
    Rpt = np.swapaxes(Rp, 1, 2)

    def mean_local(v: np.ndarray) -> np.ndarray:
        return np.mean(np.einsum("tij,tj->ti", Rpt, v), axis=0)

    up_local = mean_local(src_p[top] - pp) if top else np.linalg.inv(A) @ np.array([0.0, 0.0, 1.0]) @ Rp[0]
    if "left" in hips and "right" in hips:
        left_src = p[:, data.index(hips["left"])] - p[:, data.index(hips["right"])]
        pelvis_from = "hips"
    else:
        left_src = src_p["left_shoulder"] - src_p["right_shoulder"]
        pelvis_from = "shoulders"
    C = frame_from_axes(up_local, mean_local(left_src))
    if not np.all(np.isfinite(C)):
        raise ClipError(f"{path}: cannot orient the pelvis frame (spine parallel to the hip axis)")
    root_R = world_R["pelvis"] @ C
    clip = clip_from_world(
        path.stem,
        _fps(data.frame_time),
        world_p,
        world_p["pelvis"],
        root_R,
        world_R,
        source=f"bvh:{path.name}",
        meta={
            "path": str(path),
            "format": "bvh",
            "skeleton_map": smap.name,
            "joints": {b: s for b, s in bones.items()},
            "units": units,
            "up": up,
            "position_mode": position_mode,
            "pelvis_frame_from": pelvis_from,
            "parse_s": time.perf_counter() - t_start,
        },
    )
    return clip


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
