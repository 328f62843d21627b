"""Operator calibration: rest pose ``H_ps`` and extents ``H_pmin``/``H_pmax`` (seed 000, eqs. 1-3).

All positions are in the operator's pelvis frame (x forward, y left, z up) [m],
orientations are wxyz quaternions of the bone frame in that pelvis frame.

Three ways to get one:

* :func:`anthropometric` from a single rest frame (arms hanging): rest = that frame;
  extents = the bounding box of the sphere each arm can sweep, centred on the
  shoulder, with radius = the operator's measured arm length (upper arm + forearm
  for the wrist, upper arm for the elbow) times a per-axis reach fraction (default
  1.0 on every side). It is symmetric like the robot's Monte Carlo box, so the
  hanging rest maps near the bottom centre of the robot box, below the shoulder.
* :func:`from_recording` from a calibration recording or the clip itself: rest =
  one frame (default the first), extents = the anthropometric box united with the
  per-axis min/max actually observed, so every recorded sample lies inside.
* a JSON (or TOML) file written by :meth:`Calibration.save`.

Every side of every box is widened to at least :data:`MIN_SPAN` [m] from the rest
value so eqs. (1) and (3) never divide by ~0.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from shared.messages import HumanFrame
from shared.mirror import mirror_points, mirror_quats, other_side
from shared.targets import SIDES, TARGET_NAMES, elbow_of, wrist_of

#: Bones that must be valid for an anthropometric calibration of each arm.
ARM_BONES = {side: (f"{side}_shoulder", f"{side}_elbow", f"{side}_wrist") for side in SIDES}
#: Smallest distance between the rest value and each extent [m].
MIN_SPAN = 0.02
#: Operator arm length, shoulder to wrist [m], assumed by :func:`from_wrists` (adult median ~0.55-0.6).
DEFAULT_ARM_LENGTH = 0.55
#: Share of the arm length that is the upper arm (adult anthropometry: ~0.30 of ~0.55 m).
UPPER_ARM_SHARE = 0.55
#: Default reach fractions of the arm length (negative side, positive side) per axis x, y, z.
DEFAULT_REACH = ((1.0, 1.0), (1.0, 1.0), (1.0, 1.0))


class CalibrationError(ValueError):
    """A calibration that cannot be built or read; the text says why."""


def _vec3(x, where: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: expected 3 numbers, got {x!r}") from None
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{where}: not finite ({x!r})")
    return a


def _quat(x, where: str) -> np.ndarray:
    try:
        q = np.asarray(x, dtype=float).reshape(4)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}: expected 4 numbers (w, x, y, z), got {x!r}") from None
    n = float(np.linalg.norm(q))
    if not np.isfinite(n) or abs(n - 1.0) > 1e-3:
        raise CalibrationError(f"{where}: quaternion norm {n} is not 1 (w, x, y, z expected)")
    return q / n


@dataclass
class Calibration:
    """Operator rest pose and extents per target (``left_wrist``, ... see ``TARGET_NAMES``).

    Attributes:
        rest: target -> (3,) ``H_ps`` [m], pelvis frame.
        rest_q: target -> (4,) wxyz rest orientation ``W_R_H`` of the source bone.
        lower, upper: target -> (3,) ``H_pmin``, ``H_pmax`` [m].
        source: how it was made ("anthropometric", "recording:<name>", "file:<path>", ...).
        arm_length: side -> measured arm length [m] (informative).
    """

    rest: dict[str, np.ndarray]
    rest_q: dict[str, np.ndarray]
    lower: dict[str, np.ndarray]
    upper: dict[str, np.ndarray]
    source: str = "manual"
    arm_length: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check shapes and ordering ``lower < rest < upper``.

        Raises:
            CalibrationError: what is wrong, naming the target and axis.
        """
        for part in ("rest", "rest_q", "lower", "upper"):
            d = getattr(self, part)
            missing = [t for t in TARGET_NAMES if t not in d]
            if missing:
                raise CalibrationError(f"calibration {part} lacks targets {missing}")
            unknown = [t for t in d if t not in TARGET_NAMES]
            if unknown:
                raise CalibrationError(f"calibration {part} has unknown targets {unknown}; known {list(TARGET_NAMES)}")
        for t in TARGET_NAMES:
            self.rest[t] = _vec3(self.rest[t], f"rest.{t}")
            self.rest_q[t] = _quat(self.rest_q[t], f"rest_q.{t}")
            self.lower[t] = _vec3(self.lower[t], f"lower.{t}")
            self.upper[t] = _vec3(self.upper[t], f"upper.{t}")
            for ax, name in enumerate("xyz"):
                if not self.lower[t][ax] < self.upper[t][ax]:
                    raise CalibrationError(
                        f"{t}.{name}: lower {self.lower[t][ax]:.4f} must be < upper {self.upper[t][ax]:.4f}"
                    )
                if not self.rest[t][ax] < self.upper[t][ax]:
                    # eq. (3) divides by H_pmax - H_ps
                    raise CalibrationError(
                        f"{t}.{name}: rest {self.rest[t][ax]:.4f} must be < upper {self.upper[t][ax]:.4f} (eq. 3)"
                    )

    # ------------------------------------------------------------------ (de)serialisation

    def to_dict(self) -> dict:
        """JSON-able dict (lists of floats)."""

        def fl(d: Mapping[str, np.ndarray]) -> dict:
            return {t: [float(v) for v in d[t]] for t in TARGET_NAMES}

        return {
            "version": 1,
            "source": self.source,
            "arm_length": {k: float(v) for k, v in self.arm_length.items()},
            "rest": fl(self.rest),
            "rest_q": fl(self.rest_q),
            "lower": fl(self.lower),
            "upper": fl(self.upper),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> Calibration:
        """Inverse of :meth:`to_dict`.

        Raises:
            CalibrationError: missing or malformed fields.
        """
        if not isinstance(d, Mapping):
            raise CalibrationError(f"calibration must be a map, got {type(d).__name__}")
        try:
            return cls(
                rest=dict(d["rest"]),
                rest_q=dict(d["rest_q"]),
                lower=dict(d["lower"]),
                upper=dict(d["upper"]),
                source=str(d.get("source", "manual")),
                arm_length={str(k): float(v) for k, v in dict(d.get("arm_length", {})).items()},
            )
        except KeyError as exc:
            raise CalibrationError(f"calibration lacks field {exc}") from None
        except (TypeError, ValueError) as exc:
            if isinstance(exc, CalibrationError):
                raise
            raise CalibrationError(f"malformed calibration: {exc}") from None

    def save(self, path: str | Path) -> Path:
        """Write JSON to ``path`` (parents created)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # Write then rename: a kill mid-write leaves the previous file, never a truncated one.
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a JSON or TOML calibration file.

        Raises:
            CalibrationError: unreadable file or content.
        """
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise CalibrationError(f"cannot read calibration {path}: {exc}") from None
        try:
            d = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
        except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
            raise CalibrationError(f"{path}: not valid {path.suffix.lstrip('.') or 'JSON'}: {exc}") from None
        cal = cls.from_dict(d)
        if cal.source == "manual":
            cal.source = f"file:{path.name}"
        return cal


# ---------------------------------------------------------------------- builders


def _bone_p(frame: HumanFrame, name: str) -> np.ndarray:
    bone = frame.bones.get(name)
    if bone is None or not bone.valid:
        raise CalibrationError(f"bone {name!r} missing or invalid in frame seq {frame.hdr.seq}")
    return np.asarray(bone.p, dtype=float)


def _bone_q(frame: HumanFrame, name: str) -> np.ndarray:
    bone = frame.bones.get(name)
    if bone is None or not bone.valid:
        raise CalibrationError(f"bone {name!r} missing or invalid in frame seq {frame.hdr.seq}")
    return np.asarray(bone.q, dtype=float)


def _widen(lo: np.ndarray, rest: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.minimum(lo, rest - MIN_SPAN), np.maximum(hi, rest + MIN_SPAN)


def _mirror_arm(src_side: str, dst_side: str, rest: dict, rest_q: dict, lower: dict, upper: dict) -> None:
    """Give ``dst_side``'s wrist and elbow the mirror image of ``src_side``'s calibration, in place."""
    for src, dst in ((wrist_of(src_side), wrist_of(dst_side)), (elbow_of(src_side), elbow_of(dst_side))):
        rest[dst] = mirror_points(rest[src])
        rest_q[dst] = mirror_quats(rest_q[src])
        a, b = mirror_points(lower[src]), mirror_points(upper[src])
        lower[dst], upper[dst] = np.minimum(a, b), np.maximum(a, b)


def anthropometric(
    frame: HumanFrame,
    bone_of: Mapping[str, str] | None = None,
    reach: tuple[tuple[float, float], ...] = DEFAULT_REACH,
) -> Calibration:
    """Calibration from one rest frame (arms hanging) and arm lengths measured in it.

    Args:
        frame: operator at rest; needs valid shoulder, elbow and wrist of at least one arm.
        bone_of: target -> source bone (default: same name, e.g. the robot profile's ``human`` table).
        reach: per axis x, y, z the (negative, positive) reach as fractions of the arm length.

    An arm whose bones are missing or invalid is mirrored from the other one (one-armed
    captures); ``source`` then says so.

    Raises:
        CalibrationError: neither arm has valid bones, or an arm has ~zero length.
    """
    bone_of = dict(bone_of or {t: t for t in TARGET_NAMES})
    reach_arr = np.asarray(reach, dtype=float)
    if reach_arr.shape != (3, 2) or np.any(reach_arr <= 0):
        raise CalibrationError(f"reach must be 3 (negative, positive) positive pairs, got {reach!r}")
    rest, rest_q, lower, upper, lengths = {}, {}, {}, {}, {}
    failures = {}
    for side, (sh, el, wr) in ARM_BONES.items():
        try:
            p_sh, p_el, p_wr = _bone_p(frame, sh), _bone_p(frame, el), _bone_p(frame, wr)
            targets = {t: _bone_p(frame, bone_of[t]) for t in (wrist_of(side), elbow_of(side))}
            quats = {t: _bone_q(frame, bone_of[t]) for t in targets}
        except CalibrationError as exc:
            failures[side] = str(exc)
            continue
        upper_arm = float(np.linalg.norm(p_el - p_sh))
        forearm = float(np.linalg.norm(p_wr - p_el))
        if upper_arm < 0.05 or forearm < 0.05:
            raise CalibrationError(f"{side} arm segments {upper_arm:.3f} m / {forearm:.3f} m too short (units?)")
        lengths[side] = upper_arm + forearm
        for target, radius in ((wrist_of(side), upper_arm + forearm), (elbow_of(side), upper_arm)):
            rest[target] = targets[target]
            rest_q[target] = quats[target]
            lo = p_sh - radius * reach_arr[:, 0]
            hi = p_sh + radius * reach_arr[:, 1]
            lower[target], upper[target] = _widen(lo, rest[target], hi)
    if len(failures) == 2:
        raise CalibrationError(f"no arm can be calibrated: {'; '.join(failures.values())}")
    source = "anthropometric"
    for side in failures:
        # One-armed capture (e.g. a right-arm marker set): mirror the measured arm across the
        # sagittal plane so the calibration is complete; the missing arm's targets stay invalid
        # until its bones arrive, and then map with a plausible mirrored calibration.
        other = other_side(side)
        _mirror_arm(other, side, rest, rest_q, lower, upper)
        lengths[side] = lengths[other]
        source = f"anthropometric ({side} mirrored from {other}: {failures[side]})"
    return Calibration(rest, rest_q, lower, upper, source=source, arm_length=lengths)


def from_wrists(
    frame: HumanFrame,
    bone_of: Mapping[str, str] | None = None,
    arm_length: float = DEFAULT_ARM_LENGTH,
    reach: tuple[tuple[float, float], ...] = DEFAULT_REACH,
) -> Calibration:
    """Calibration from one rest frame of a wrist-only source (VR controllers: hands, no arm bones).

    Without shoulders nothing measures the arm, so the operator's arm length is given
    (``arm_length`` [m], default :data:`DEFAULT_ARM_LENGTH`) and the shoulder is taken straight
    above the hanging wrist. The boxes are then those of :func:`anthropometric` around that
    shoulder. Elbow entries are filled for completeness (rest straight below the shoulder at the
    upper-arm share of the length); a wrist-only source never makes elbow targets valid.

    Raises:
        CalibrationError: no valid wrist, or a non-positive arm length.
    """
    bone_of = dict(bone_of or {t: t for t in TARGET_NAMES})
    if not arm_length > 0.1:
        raise CalibrationError(f"arm length {arm_length} m must be > 0.1 m")
    reach_arr = np.asarray(reach, dtype=float)
    rest, rest_q, lower, upper, lengths = {}, {}, {}, {}, {}
    failures = {}
    up = np.array([0.0, 0.0, 1.0])
    for side in ("left", "right"):
        try:
            wrist = _bone_p(frame, bone_of[f"{side}_wrist"])
            wrist_q = _bone_q(frame, bone_of[f"{side}_wrist"])
        except CalibrationError as exc:
            failures[side] = str(exc)
            continue
        shoulder = wrist + arm_length * up
        elbow = shoulder - UPPER_ARM_SHARE * arm_length * up
        lengths[side] = arm_length
        for target, p, radius in (
            (f"{side}_wrist", wrist, arm_length),
            (f"{side}_elbow", elbow, UPPER_ARM_SHARE * arm_length),
        ):
            rest[target] = p
            rest_q[target] = wrist_q
            lower[target], upper[target] = _widen(
                shoulder - radius * reach_arr[:, 0], p, shoulder + radius * reach_arr[:, 1]
            )
    if len(failures) == 2:
        raise CalibrationError(f"no wrist to calibrate from: {'; '.join(failures.values())}")
    source = f"wrists (arm length {arm_length:g} m assumed)"
    for side in failures:
        other = other_side(side)
        _mirror_arm(other, side, rest, rest_q, lower, upper)
        lengths[side] = lengths[other]
        source += f" ({side} mirrored from {other})"
    return Calibration(rest, rest_q, lower, upper, source=source, arm_length=lengths)


def from_recording(
    frames: Iterable[HumanFrame],
    rest_index: int = 0,
    bone_of: Mapping[str, str] | None = None,
    include_anthropometric: bool = True,
    name: str = "recording",
) -> Calibration:
    """Calibration from a calibration recording or the clip itself.

    Args:
        frames: the recording's HumanFrames (invalid bones are ignored for the extents).
        rest_index: index of the frame where the operator stands at rest (arms hanging).
        bone_of: target -> source bone (default same name).
        include_anthropometric: unite the observed extents with the anthropometric box of the
            rest frame, so small motions are not blown up to the whole robot workspace.
        name: recorded in ``source``.

    Raises:
        CalibrationError: no valid rest frame or no valid samples of a target.
    """
    frames = list(frames)
    if not frames:
        raise CalibrationError("empty recording")
    if not -len(frames) <= rest_index < len(frames):
        raise CalibrationError(f"rest_index {rest_index} outside the {len(frames)} frames")
    bone_of = dict(bone_of or {t: t for t in TARGET_NAMES})
    base = anthropometric(frames[rest_index], bone_of)
    lower, upper = {}, {}
    for t in TARGET_NAMES:
        pts = [f.bones[bone_of[t]].p for f in frames if bone_of[t] in f.bones and f.bones[bone_of[t]].valid]
        if not pts:
            raise CalibrationError(f"no valid samples of bone {bone_of[t]!r} in the recording")
        pts = np.asarray(pts, dtype=float)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if include_anthropometric:
            lo, hi = np.minimum(lo, base.lower[t]), np.maximum(hi, base.upper[t])
        lower[t], upper[t] = _widen(lo, base.rest[t], hi)
    return Calibration(base.rest, base.rest_q, lower, upper, source=f"recording:{name}", arm_length=base.arm_length)
