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

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from services.ingest.body_frame import left_axis, unit_scale, up_axis
from services.ingest.clip import Clip, clip_from_file
from services.ingest.errors import C3dError
from services.ingest.map_files import name_list, read_map_file
from services.ingest.rotations import frame_from_axes
from shared.messages import HUMAN_BONES

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
        elbow_offset: [m] from a lone lateral epicondyle marker to the elbow centre (half the elbow's width plus
            the marker's radius), along the flexion axis; 0 when the elbow markers straddle the joint (their mean
            is the centre).
    """

    name: str
    joints: dict[str, tuple[str, ...]]
    pelvis: dict[str, str] = field(default_factory=dict)
    thorax: dict[str, tuple[str, ...]] = field(default_factory=dict)
    shoulder_drop: float = 0.17
    elbow_offset: float = 0.0

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


def _vicon_full_body(name: str, pelvis: tuple[str, str, str, str]) -> MarkerMap:
    """Vicon's full-body marker sets: Plug-in Gait names on the trunk, head and arms (the elbow has only its lateral
    epicondyle marker, moved to the centre by half a typical adult elbow width, 7 cm, plus a 14 mm marker's radius;
    the wrist is the mean of the radial and ulnar styloid bars, the hand tip the second metacarpal head); ``pelvis``
    names the left / right front and back markers."""
    arm = (("shoulder", ("SHO",)), ("elbow", ("ELB",)), ("wrist", ("WRA", "WRB")), ("hand", ("FIN",)))
    return MarkerMap(
        name,
        {
            "chest": ("CLAV", "STRN", "C7", "T10"),
            "neck": ("CLAV", "C7"),
            "head": ("LFHD", "LBHD", "RFHD", "RBHD"),
            **{f"{side}_{b}": tuple(S + m for m in ms) for side, S in (("left", "L"), ("right", "R")) for b, ms in arm},
        },
        dict(zip(_PELVIS_KEYS, pelvis)),
        {"top": ("CLAV", "C7"), "bottom": ("STRN", "T10")},
        elbow_offset=0.042,
    )


#: Vicon Plug-in Gait (full body), the most common clinical and lab marker set: pelvis on ASIS / PSIS.
PLUG_IN_GAIT = _vicon_full_body("plug_in_gait", ("LASI", "RASI", "LPSI", "RPSI"))
#: The CMU Graphics Lab motion capture database's 41-marker set: Plug-in Gait names, pelvis on four waist markers.
CMU_WAIST = _vicon_full_body("cmu_41", ("LFWT", "RFWT", "LBWT", "RBWT"))

BUILTIN_MARKER_MAPS: tuple[MarkerMap, ...] = (VICON_SHOULDER, QUALISYS_ISB, PLUG_IN_GAIT, CMU_WAIST)


def load_marker_map(path: str | Path) -> MarkerMap:
    """Read a marker map file (TOML or JSON)::

        name = "my_lab"
        shoulder_drop = 0.17
        elbow_offset = 0.0             # [m], a lone lateral elbow marker to the centre
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
    d = read_map_file(path, "marker map", C3dError)

    def names(v: Any, where: str) -> tuple[str, ...]:
        return name_list(v, f"marker map {path}: {where} must be a marker name", C3dError)

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
    elbow_offset = d.get("elbow_offset", 0.0)
    if isinstance(elbow_offset, bool) or not isinstance(elbow_offset, int | float) or not 0.0 <= elbow_offset <= 0.1:
        raise C3dError(f"marker map {path}: elbow_offset must be a number of metres in [0, 0.1], got {elbow_offset!r}")
    return MarkerMap(
        str(d.get("name", path.stem)),
        {b: names(v, f"joints.{b}") for b, v in joints.items()},
        {k: str(v) for k, v in pelvis.items()},
        {k: names(v, f"thorax.{k}") for k, v in thorax.items()},
        float(d.get("shoulder_drop", 0.17)),
        float(elbow_offset),
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


def _open_c3d(path: Path) -> tuple[list[str], np.ndarray, str, float]:
    """Labels, (3, n_markers, T) points [file units], unit and rate [Hz] of a C3D file."""
    import ezc3d

    if not path.is_file():
        raise C3dError(f"{path}: no such file")
    try:
        c = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises plain RuntimeError/IOError on corrupt files
        raise C3dError(f"{path}: ezc3d cannot read it ({type(exc).__name__}: {exc})") from None
    params = c["parameters"]["POINT"]
    labels = [str(s).strip() for s in params["LABELS"]["value"]]
    pts = np.asarray(c["data"]["points"][:3], dtype=float)
    unit = str(params["UNITS"]["value"][0]).strip().lower() if "UNITS" in params else "mm"
    rate = float(np.asarray(params["RATE"]["value"]).ravel()[0])
    if not rate > 0:
        raise C3dError(f"{path}: POINT:RATE must be > 0, got {rate}")
    return labels, pts, unit, rate


class _Markers:
    """One subject's marker trajectories, (T, 3) [m] by name; occluded (NaN or zeroed) samples are NaN."""

    def __init__(self, labels: list[str], pts: np.ndarray, scale: float, prefix: str) -> None:
        self.index = {lb: i for i, lb in enumerate(labels)}
        self.xyz = np.moveaxis(pts, 0, -1) * scale  # (n_markers, T, 3)
        self.xyz[np.all(self.xyz == 0.0, axis=-1)] = np.nan
        self.prefix = prefix

    def get(self, name: str) -> np.ndarray | None:
        i = self.index.get(self.prefix + name)
        return None if i is None else self.xyz[i]

    def mean(self, names: tuple[str, ...]) -> np.ndarray | None:
        """Mean of the markers (NaN where any is occluded, by design), None if one is missing."""
        arrs = [self.get(n) for n in names]
        if any(a is None for a in arrs):
            return None
        return np.mean(arrs, axis=0)


@dataclass
class _Landmarks:
    """Joint centres and root markers of a clip, (T, 3) [m] in the file's axes (or our Z-up ones).

    Attributes:
        joints: canonical bone -> centre. pelvis: _PELVIS_KEYS -> marker, or None (not all in the file).
        thorax: (top, bottom) marker means, or None. top_pair: the first two top markers, or None.
    """

    joints: dict[str, np.ndarray]
    pelvis: dict[str, np.ndarray] | None
    thorax: tuple[np.ndarray, np.ndarray] | None
    top_pair: tuple[np.ndarray, np.ndarray] | None

    @classmethod
    def find(cls, m: _Markers, mmap: MarkerMap) -> _Landmarks:
        joints = {b: v for b, ms in mmap.joints.items() if (v := m.mean(ms)) is not None}
        pelvis = {k: m.get(v) for k, v in mmap.pelvis.items()}
        thorax = (m.mean(mmap.thorax["top"]), m.mean(mmap.thorax["bottom"])) if mmap.thorax else (None, None)
        complete = thorax[0] is not None and thorax[1] is not None
        return cls(
            joints,
            pelvis if pelvis and all(v is not None for v in pelvis.values()) else None,
            thorax if complete else None,
            tuple(m.get(n) for n in mmap.thorax["top"][:2]) if complete else None,
        )

    def arms(self) -> list[str]:
        return [s for s in ("left", "right") if f"{s}_elbow" in self.joints and f"{s}_wrist" in self.joints]

    def trunk(self) -> np.ndarray | None:
        """(T, 3) lower -> upper trunk vectors, or None."""
        if self.pelvis is not None:
            base = np.nanmean(np.stack(list(self.pelvis.values())), axis=0)
            shoulder = self.joints.get(f"{self.arms()[0]}_shoulder")
            top = self.thorax[0] if self.thorax else self.joints.get("neck", shoulder)
        else:
            base, top = self.thorax[1], self.thorax[0]
        return None if top is None else top - base

    def rotated(self, A: np.ndarray) -> _Landmarks:
        """The same landmarks in the axes ``p' = A @ p``."""

        def rot(v):
            return None if v is None else v @ A.T

        return _Landmarks(
            {b: rot(v) for b, v in self.joints.items()},
            None if self.pelvis is None else {k: rot(v) for k, v in self.pelvis.items()},
            None if self.thorax is None else (rot(self.thorax[0]), rot(self.thorax[1])),
            None if self.top_pair is None else (rot(self.top_pair[0]), rot(self.top_pair[1])),
        )

    def root_frame(self) -> tuple[np.ndarray, np.ndarray, str]:
        """Root origin (T, 3), axes (T, 3, 3) (NaN where occluded) and what they came from."""
        if self.pelvis is not None:
            P = self.pelvis
            left, _ = left_axis([("pelvis", P["left_front"], P["right_front"])])
            fwd = 0.5 * (P["left_front"] + P["right_front"]) - 0.5 * (P["left_back"] + P["right_back"])
            root_p = np.mean([P[k] for k in _PELVIS_KEYS], axis=0)
            return root_p, frame_from_axes(np.cross(fwd, left), left), "pelvis"
        top, bottom = self.thorax
        shoulders = left_axis([("shoulders", self.joints.get("left_shoulder"), self.joints.get("right_shoulder"))])
        if shoulders is not None:
            left = shoulders[0]
        else:
            # sternum-side minus spine-side marker of the top pair points forward
            t0, t1 = self.top_pair
            left = np.cross(top - bottom, t0 - t1)
        return bottom, frame_from_axes(top - bottom, left), "thorax"


#: Sine of the elbow flexion (about 14 deg) below which the lateral marker's shift to the centre fades out.
ELBOW_AXIS_SINE = 0.25


def _medial_elbows(joints: dict[str, np.ndarray], offset: float) -> dict[str, np.ndarray]:
    """Lateral epicondyle marker -> elbow centre: moved ``offset`` [m] medially along the flexion axis.

    The axis is normal to the plane of the upper arm (acromion -> marker) and the forearm (marker -> wrist), pointing
    laterally (the left arm's to the left). Below :data:`ELBOW_AXIS_SINE` of flexion the shift fades out with the
    sine, as the arm straightens: there the axis is undefined, and the elbow sits on the shoulder-wrist line whatever
    its swivel.
    """
    out = dict(joints)
    for s, lateral in (("left", -1.0), ("right", 1.0)):
        sh, el, wr = (out.get(f"{s}_{b}") for b in ("shoulder", "elbow", "wrist"))
        if sh is None or el is None or wr is None or not offset:
            continue
        u, f = el - sh, wr - el
        lengths = np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(f, axis=1), 1e-12)  # coincident markers
        n = np.cross(u, f) / lengths[:, None]  # |n| = sin(flexion)
        n /= np.maximum(np.linalg.norm(n, axis=1), ELBOW_AXIS_SINE)[:, None]
        out[f"{s}_elbow"] = el - offset * lateral * n
    return out


def _lower_shoulders(joints: dict[str, np.ndarray], z_root: np.ndarray, drop: float) -> dict[str, np.ndarray]:
    """Acromion -> gleno-humeral centre: lowered along the root z (T, 3) by drop * |acromion - elbow|."""
    out = dict(joints)
    for s in ("left", "right"):
        sh, el = out.get(f"{s}_shoulder"), out.get(f"{s}_elbow")
        if sh is not None and el is not None and drop:
            out[f"{s}_shoulder"] = sh - drop * np.linalg.norm(sh - el, axis=1, keepdims=True) * z_root
    return out


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
    t_start = time.perf_counter()
    path = Path(path)
    labels, pts, unit, rate = _open_c3d(path)
    unit, scale = unit_scale(unit, where=f"{path}: POINT:UNITS", error=C3dError)
    maps = BUILTIN_MARKER_MAPS if marker_map is None else (_as_marker_map(marker_map),)
    mmap, pre, n_found = _choose(labels, maps, prefix)
    found = _Landmarks.find(_Markers(labels, pts, scale, pre), mmap)
    arms = found.arms()
    if not arms or not (found.pelvis or found.thorax):
        wanted = [b for b in HUMAN_BONES[1:] if b not in found.joints]
        raise C3dError(
            f"{path}: marker map '{mmap.name}' (prefix {pre!r}) found {n_found} of its markers; "
            f"{'no elbow+wrist pair' if not arms else 'no pelvis or thorax markers for the root frame'}. "
            f"Unmapped bones: {wanted}. Labels in the file: {labels}. Pass a marker map file (see README)."
        )
    trunk = found.trunk()
    up, A = up_axis(up, np.array([[0.0, 0.0, 1.0]]) if trunk is None else trunk, str(path), C3dError)
    found = found.rotated(A)
    root_p, root_R, root_from = found.root_frame()
    world = _lower_shoulders(_medial_elbows(found.joints, mmap.elbow_offset), root_R[:, :, 2], mmap.shoulder_drop)
    meta = {"marker_map": mmap.name, "prefix": pre, "units": unit, "up": up, "root_from": root_from}
    return clip_from_file(path, "c3d", rate, world, root_p, root_R, None, t_start, meta)


def _as_marker_map(marker_map: MarkerMap | str | Path) -> MarkerMap:
    return marker_map if isinstance(marker_map, MarkerMap) else load_marker_map(marker_map)
