"""C3D marker files (through ezc3d) -> canonical :class:`~services.ingest.clip.Clip`.

Joint centres come from a :class:`MarkerMap`: each canonical bone is the mean
of its markers (elbow from the epicondyle pair, wrist from the styloid pair,
...) and is invalid in any frame where one of them is occluded (NaN in ezc3d,
or an exact zero vector from writers that zero gaps); never zero-filled. The
shoulder (gleno-humeral centre) is the acromion marker lowered along the root
frame's z by ``shoulder_drop`` times the acromion-elbow distance (0.17 after
Rab et al. 2002; 0 keeps the acromion).

Root frame: from the four pelvis markers when the map has them (origin at
their mean; y from right to left ASIS; x forward from the PSIS midpoint to
the ASIS midpoint; z up), else from the thorax (origin at the lower-thorax
midpoint, z from lower to upper thorax markers, y from the right to the left
acromion if both exist, else perpendicular to z and the sternum-spine
direction). C3D gives no bone orientations: quaternions are identity and
``Clip.has_orientation`` is False; ``valid`` is about positions only.
"""

from __future__ import annotations

import json
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from services.ingest.clip import Clip, clip_from_world
from services.ingest.errors import C3dError, ClipError
from services.ingest.rotations import Y_UP_TO_Z_UP, frame_from_axes
from shared.messages import HUMAN_BONES

_UNITS = {"mm": 0.001, "cm": 0.01, "m": 1.0}
_PELVIS_KEYS = ("left_front", "right_front", "left_back", "right_back")


@dataclass(frozen=True)
class MarkerMap:
    """Marker names -> joint centres and root frame.

    Attributes:
        name: map name.
        joints: canonical bone -> markers whose mean is the joint centre.
        pelvis: "left_front", "right_front", "left_back", "right_back" -> marker (ASIS/PSIS), or empty.
        thorax: "top" / "bottom" -> markers (e.g. sternum notch + C7 / xiphoid + T10), or empty.
        shoulder_drop: shoulder centre = acromion - drop * |acromion - elbow| * z_root.
    """

    name: str
    joints: dict[str, tuple[str, ...]]
    pelvis: dict[str, str] = field(default_factory=dict)
    thorax: dict[str, tuple[str, ...]] = field(default_factory=dict)
    shoulder_drop: float = 0.17

    def markers(self) -> set[str]:
        out = {m for ms in self.joints.values() for m in ms} | set(self.pelvis.values())
        return out | {m for ms in self.thorax.values() for m in ms}


#: Vicon "EpauleDroiteStatique" set of the ezc3d test file (subject prefix ``Daphnee:``): right arm + trunk.
VICON_SHOULDER = MarkerMap(
    "vicon_epaule_droite",
    {
        "chest": ("STER", "XIPH", "T1", "T10"),
        "neck": ("STER", "T1"),
        "right_clavicle": ("CLAV_SC",),
        "right_shoulder": ("ACRO_tip",),
        "right_elbow": ("EPICl", "EPICm"),
        "right_wrist": ("STYLr", "STYLu"),
        "right_hand": ("INDEX", "LASTC"),
    },
    {"left_front": "ASISl", "right_front": "ASISr", "left_back": "PSISl", "right_back": "PSISr"},
    {"top": ("STER", "T1"), "bottom": ("XIPH", "T10")},
)

#: Qualisys / ISB-style full-body names (ezc3d Qualisys test file).
QUALISYS_ISB = MarkerMap(
    "qualisys_isb",
    {
        "chest": ("SNJ", "SXS", "CV7", "TV8"),
        "neck": ("SNJ", "CV7"),
        "head": ("L_HDF", "L_HDB", "R_HDF", "R_HDB"),
        **{
            f"{side}_{bone}": tuple(f"{S}_{m}" for m in ms)
            for side, S in (("left", "L"), ("right", "R"))
            for bone, ms in (
                ("shoulder", ("SAJ",)),
                ("elbow", ("HLE", "HME")),
                ("wrist", ("RSP", "UHE")),
                ("hand", ("HM2", "HM5")),
            )
        },
    },
    {"left_front": "L_IAS", "right_front": "R_IAS", "left_back": "L_IPS", "right_back": "R_IPS"},
    {"top": ("SNJ", "CV7"), "bottom": ("SXS", "TV8")},
)

BUILTIN_MARKER_MAPS: tuple[MarkerMap, ...] = (VICON_SHOULDER, QUALISYS_ISB)


def load_marker_map(path: str | Path) -> MarkerMap:
    """Read a marker map file (TOML or JSON)::

        name = "my_lab"
        shoulder_drop = 0.17
        [joints]                       # canonical bone -> marker or list of markers (mean)
        right_elbow = ["RELB_LAT", "RELB_MED"]
        right_wrist = ["RWRA", "RWRB"]
        right_shoulder = "RSHO"
        [pelvis]                       # optional
        left_front = "LASI"
        right_front = "RASI"
        left_back = "LPSI"
        right_back = "RPSI"
        [thorax]                       # optional
        top = ["CLAV", "C7"]
        bottom = ["STRN", "T10"]

    Raises:
        C3dError: unreadable file or unknown keys.
    """
    path = Path(path)
    try:
        text = path.read_text()
        d = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, ValueError) as exc:
        raise C3dError(f"marker map {path}: cannot read ({exc})") from None

    def names(v: Any, where: str) -> tuple[str, ...]:
        if isinstance(v, str):
            return (v,)
        if isinstance(v, list) and v and all(isinstance(x, str) for x in v):
            return tuple(v)
        raise C3dError(f"marker map {path}: {where} must be a marker name or a list of names")

    joints = d.get("joints")
    if not isinstance(joints, dict) or not joints:
        raise C3dError(f"marker map {path}: missing [joints] table")
    bad = [b for b in joints if b not in HUMAN_BONES or b == "pelvis"]
    if bad:
        raise C3dError(f"marker map {path}: unknown joints {bad}; known: {list(HUMAN_BONES[1:])}")
    pelvis = d.get("pelvis", {})
    if pelvis and set(pelvis) != set(_PELVIS_KEYS):
        raise C3dError(f"marker map {path}: [pelvis] needs exactly {list(_PELVIS_KEYS)}")
    thorax = d.get("thorax", {})
    if thorax and set(thorax) != {"top", "bottom"}:
        raise C3dError(f"marker map {path}: [thorax] needs 'top' and 'bottom'")
    return MarkerMap(
        str(d.get("name", path.stem)),
        {b: names(v, f"joints.{b}") for b, v in joints.items()},
        {k: str(v) for k, v in pelvis.items()},
        {k: names(v, f"thorax.{k}") for k, v in thorax.items()},
        float(d.get("shoulder_drop", 0.17)),
    )


def _split(label: str) -> tuple[str, str]:
    prefix, _, base = label.rpartition(":")
    return (prefix + ":" if prefix else ""), base


def _choose(labels: list[str], maps: tuple[MarkerMap, ...], prefix: str | None) -> tuple[MarkerMap, str, int]:
    """Best (map, subject prefix) by number of the map's markers present."""
    prefixes = sorted({_split(lb)[0] for lb in labels}) if prefix is None else [prefix]
    have = set(labels)
    best = None
    for m in maps:
        for pre in prefixes:
            n = sum(pre + mk in have for mk in m.markers())
            if best is None or n > best[2]:
                best = (m, pre, n)
    assert best is not None
    return best


def read_c3d_clip(
    path: str | Path,
    marker_map: MarkerMap | str | Path | None = None,
    prefix: str | None = None,
    up: str = "auto",
) -> Clip:
    """Read a C3D file's markers as a canonical :class:`Clip` (joint centres, no orientations).

    Args:
        path: C3D file.
        marker_map: a map, a map file, or None to pick the best built-in map.
        prefix: subject prefix of the labels (``"Daphnee:"``); auto when None.
        up: vertical axis of the file ("z", "y" or "auto" from the thorax/pelvis direction).

    Raises:
        C3dError: unreadable file, no usable root or arm markers (the text lists the labels found).
    """
    import ezc3d

    t_start = time.perf_counter()
    path = Path(path)
    if not path.is_file():
        raise C3dError(f"{path}: no such file")
    try:
        c = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises plain RuntimeError/IOError on corrupt files
        raise C3dError(f"{path}: ezc3d cannot read it ({type(exc).__name__}: {exc})") from None
    params = c["parameters"]["POINT"]
    labels = [str(s).strip() for s in params["LABELS"]["value"]]
    pts = np.asarray(c["data"]["points"][:3], dtype=float)  # (3, n_markers, T)
    unit = str(params["UNITS"]["value"][0]).strip().lower() if "UNITS" in params else "mm"
    if unit not in _UNITS:
        raise C3dError(f"{path}: unknown POINT:UNITS {unit!r}; supported: {list(_UNITS)}")
    rate = float(np.asarray(params["RATE"]["value"]).ravel()[0])
    if not rate > 0:
        raise C3dError(f"{path}: POINT:RATE must be > 0, got {rate}")

    if marker_map is None:
        mmap, pre, n_found = _choose(labels, BUILTIN_MARKER_MAPS, prefix)
    else:
        mmap = marker_map if isinstance(marker_map, MarkerMap) else load_marker_map(marker_map)
        mmap, pre, n_found = _choose(labels, (mmap,), prefix)
    index = {lb: i for i, lb in enumerate(labels)}
    # (T, 3) per marker in metres; occluded or zeroed -> NaN
    xyz = np.moveaxis(pts, 0, -1) * _UNITS[unit]  # (n_markers, T, 3)
    xyz[np.all(xyz == 0.0, axis=-1)] = np.nan

    def marker(name: str) -> np.ndarray | None:
        i = index.get(pre + name)
        return None if i is None else xyz[i]

    def mean(names: tuple[str, ...]) -> np.ndarray | None:
        arrs = [marker(n) for n in names]
        if any(a is None for a in arrs):
            return None
        return np.mean(arrs, axis=0)  # NaN if any is occluded, by design

    raw = {b: v for b, ms in mmap.joints.items() if (v := mean(ms)) is not None}
    pelvis = {k: marker(v) for k, v in mmap.pelvis.items()}
    has_pelvis = bool(pelvis) and all(v is not None for v in pelvis.values())
    top = mean(mmap.thorax["top"]) if mmap.thorax else None
    bottom = mean(mmap.thorax["bottom"]) if mmap.thorax else None
    has_thorax = top is not None and bottom is not None
    arms = [s for s in ("left", "right") if f"{s}_elbow" in raw and f"{s}_wrist" in raw]
    if not arms or not (has_pelvis or has_thorax):
        wanted = [b for b in HUMAN_BONES[1:] if b not in raw]
        raise C3dError(
            f"{path}: marker map '{mmap.name}' (prefix {pre!r}) found {n_found} of its markers; "
            f"{'no elbow+wrist pair' if not arms else 'no pelvis or thorax markers for the root frame'}. "
            f"Unmapped bones: {wanted}. Labels in the file: {labels}. Pass a marker map file (see README)."
        )

    # up axis of the file: lower -> upper trunk
    if has_pelvis:
        base = np.nanmean(np.stack(list(pelvis.values())), axis=0)
        trunk = top if has_thorax else raw.get("neck", raw.get(f"{arms[0]}_shoulder"))
    else:
        base, trunk = bottom, top
    if up == "auto":
        v = np.nanmedian(trunk - base, axis=0) if trunk is not None else np.array([0.0, 0.0, 1.0])
        k = int(np.argmax(np.abs(v)))
        if k == 0 or v[k] < 0:
            raise C3dError(f"{path}: trunk points along {'-+'[v[k] > 0]}{'XYZ'[k]}; pass up='y' or 'z'")
        up = "xyz"[k]
    if up not in ("y", "z"):
        raise ClipError(f"up {up!r}; choose auto, y or z")
    A = Y_UP_TO_Z_UP if up == "y" else np.eye(3)

    def rot(v: np.ndarray | None) -> np.ndarray | None:
        return None if v is None else v @ A.T

    raw = {b: rot(v) for b, v in raw.items()}
    if has_pelvis:
        P = {k: rot(v) for k, v in pelvis.items()}
        root_p = np.mean([P[k] for k in _PELVIS_KEYS], axis=0)
        left = P["left_front"] - P["right_front"]
        fwd = 0.5 * (P["left_front"] + P["right_front"]) - 0.5 * (P["left_back"] + P["right_back"])
        root_R = frame_from_axes(np.cross(fwd, left), left)
        root_from = "pelvis"
    else:
        top, bottom = rot(top), rot(bottom)
        root_p = bottom
        if "left_shoulder" in raw and "right_shoulder" in raw:
            left = raw["left_shoulder"] - raw["right_shoulder"]
        else:
            # sternum-side minus spine-side marker of the top pair points forward
            t0, t1 = (rot(marker(n)) for n in mmap.thorax["top"][:2])
            left = np.cross(top - bottom, t0 - t1)
        root_R = frame_from_axes(top - bottom, left)
        root_from = "thorax"

    world = dict(raw)
    zr = root_R[:, :, 2]
    for s in ("left", "right"):
        sh, el = world.get(f"{s}_shoulder"), world.get(f"{s}_elbow")
        if sh is not None and el is not None and mmap.shoulder_drop:
            world[f"{s}_shoulder"] = sh - mmap.shoulder_drop * np.linalg.norm(sh - el, axis=1, keepdims=True) * zr
    clip = clip_from_world(
        path.stem,
        rate,
        world,
        root_p,
        root_R,
        None,
        source=f"c3d:{path.name}",
        meta={
            "path": str(path),
            "format": "c3d",
            "marker_map": mmap.name,
            "prefix": pre,
            "units": unit,
            "up": up,
            "root_from": root_from,
            "parse_s": time.perf_counter() - t_start,
        },
    )
    return clip
