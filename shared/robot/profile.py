"""Robot profiles: a robot is a TOML file under ``models/``, not code."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

from shared.paths import MODELS_DIR
from shared.targets import SIDES, TARGET_NAMES

#: The robot every service and CLI uses unless told otherwise (``--robot NAME|FILE``).
DEFAULT_PROFILE = "g1_29dof"


class ProfileError(ValueError):
    """A robot profile that cannot be used; the message says why."""


@dataclass(frozen=True)
class ArmJoints:
    """The joint roles of one arm, read from the profile's ``[arms.<side>]`` table.

    Attributes:
        joints: the arm chain, shoulder to wrist, in solver order.
        elbow: the elbow joint (one of ``joints``): joints before it are the shoulder
            (they move the upper arm), joints after it the wrist (they turn the hand).
    """

    joints: tuple[str, ...]
    elbow: str

    @property
    def shoulder(self) -> tuple[str, ...]:
        """Shoulder joints: the chain before the elbow joint."""
        return self.joints[: self.joints.index(self.elbow)]

    @property
    def wrist(self) -> tuple[str, ...]:
        """Wrist joints: the chain after the elbow joint."""
        return self.joints[self.joints.index(self.elbow) + 1 :]


@dataclass(frozen=True)
class RobotProfile:
    """Everything the services need to know about one robot.

    Attributes:
        name: profile name. urdf_path: absolute URDF path.
        package_dirs: folders that ``package://`` URIs are resolved against.
        base_frame: frame all targets are expressed in.
        waist: waist joints in solver order (may be empty: an arms-only robot).
        arms: side (``left``/``right``) -> the arm's joint roles.
        frames: target name (``left_wrist``, ...; at least every ``TARGET_NAMES``) -> robot frame.
        human: target name -> canonical human bone.
        rest: joint name -> rest angle [rad] (unlisted joints rest at 0).
        max_joint_velocity: cap on every joint speed [rad/s].
        max_joint_acceleration: cap on every joint acceleration [rad/s^2].
        limit_margin: shrink of each position limit [rad].
        actuators: MuJoCo servo parameters (kp, kv, armature).
        arms_out: joint -> offset [rad] from rest holding the arms clear of the body (centre
            of the servo tracking sine).
    """

    name: str
    urdf_path: Path
    package_dirs: tuple[Path, ...]
    base_frame: str
    waist: tuple[str, ...]
    arms: dict[str, ArmJoints]
    frames: dict[str, str]
    human: dict[str, str]
    rest: dict[str, float]
    max_joint_velocity: float
    max_joint_acceleration: float
    limit_margin: float
    actuators: dict[str, float] = field(default_factory=dict)
    arms_out: dict[str, float] = field(default_factory=dict)
    source: Path | None = None

    def controlled_joints(self, with_waist: bool = True) -> tuple[str, ...]:
        """Controlled joints in solver order: waist (if asked) then each arm in ``SIDES`` order.

        (17,) with the waist, (14,) without on the G1.
        """
        return (self.waist if with_waist else ()) + tuple(j for s in SIDES for j in self.arms[s].joints)

    def mesh_uri_to_path(self, uri: str) -> Path:
        """Resolve a ``package://`` mesh URI to a file on disk."""
        if not uri.startswith("package://"):
            return Path(uri)
        rel = uri[len("package://") :]
        for root in self.package_dirs:
            cand = root / rel
            if cand.exists():
                return cand
        raise ProfileError(f"mesh {uri!r} not found under {[str(p) for p in self.package_dirs]}")


def _share_dir(distribution: str, share: str) -> Path:
    try:
        dist = metadata.distribution(distribution)
    except metadata.PackageNotFoundError:
        raise ProfileError(f"package {distribution!r} is not installed (pip install {distribution})") from None
    return Path(str(dist.locate_file(share))).resolve()


def load_profile(name_or_path: str | Path = DEFAULT_PROFILE) -> RobotProfile:
    """Load a profile by name (``models/<name>.toml``) or by path.

    Raises:
        ProfileError: unknown profile, missing fields or files.
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = MODELS_DIR / f"{name_or_path}.toml"
    if not path.exists():
        known = sorted(p.stem for p in MODELS_DIR.glob("*.toml"))
        raise ProfileError(f"robot profile {str(name_or_path)!r} not found; known profiles: {known}")
    with path.open("rb") as fh:
        raw = tomllib.load(fh)
    try:
        urdf = raw["urdf"]
        share = _share_dir(urdf["distribution"], urdf.get("share", ".")) if "distribution" in urdf else path.parent
        urdf_path = (share / urdf["path"]).resolve()
        package_root = (share / urdf.get("package_root", ".")).resolve()
        model = raw["model"]
        frames = dict(raw["frames"])
        human = dict(raw.get("human", {t: t for t in TARGET_NAMES}))
        arms = {s: _arm(raw["arms"][s], f"[arms.{s}]", path) for s in SIDES}
        prof = RobotProfile(
            name=raw.get("name", path.stem),
            urdf_path=urdf_path,
            package_dirs=(package_root,),
            base_frame=model["base_frame"],
            waist=tuple(model.get("waist", ())),
            arms=arms,
            frames=frames,
            human=human,
            rest={k: float(v) for k, v in raw.get("rest", {}).items()},
            max_joint_velocity=_number(model, "max_joint_velocity", "[model]"),
            max_joint_acceleration=_number(model, "max_joint_acceleration", "[model]"),
            limit_margin=_number(model, "limit_margin", "[model]", 0.0),
            actuators={k: float(v) for k, v in raw.get("actuators", {}).items()},
            arms_out={k: float(v) for k, v in raw.get("arms_out", {}).items()},
            source=path,
        )
    except KeyError as exc:
        raise ProfileError(f"{path}: missing field {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ProfileError(f"{path}: {exc}") from None
    _validate(prof, path)
    return prof


def _number(table: dict, key: str, where: str, default: float | None = None) -> float:
    """``table[key]`` as a float; raises KeyError when missing without a default, ValueError naming it."""
    value = table[key] if default is None else table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{where} {key} must be a number, got {value!r}")
    return float(value)


def _arm(raw: dict, where: str, path: Path) -> ArmJoints:
    joints = tuple(raw["joints"])
    elbow = raw["elbow"]
    if elbow not in joints:
        raise ProfileError(f"{path}: {where} elbow {elbow!r} is not one of its joints {list(joints)}")
    return ArmJoints(joints, elbow)


def _validate(prof: RobotProfile, path: Path) -> None:
    """Raise :class:`ProfileError` on values no robot can have (the message names the field)."""
    if not prof.urdf_path.exists():
        raise ProfileError(f"{path}: URDF {prof.urdf_path} does not exist")
    missing = [t for t in TARGET_NAMES if t not in prof.frames]
    if missing:
        raise ProfileError(f"{path}: [frames] lacks {missing}")
    joints = prof.controlled_joints()
    dup = sorted({j for j in joints if joints.count(j) > 1})
    if dup:
        raise ProfileError(f"{path}: joints {dup} are listed twice in [model] waist / [arms.*]")
    for key in ("max_joint_velocity", "max_joint_acceleration"):
        v = getattr(prof, key)
        if not (math.isfinite(v) and v > 0.0):
            raise ProfileError(f"{path}: [model] {key} must be a positive number, got {v}")
    if not (math.isfinite(prof.limit_margin) and prof.limit_margin >= 0.0):
        raise ProfileError(f"{path}: [model] limit_margin must be >= 0, got {prof.limit_margin}")
    unknown = sorted(set(prof.arms_out) - set(joints))
    if unknown:
        raise ProfileError(f"{path}: [arms_out] names joints that are not controlled: {unknown}")


def upper_arm_frame(profile: RobotProfile, side: str) -> str:
    """Robot frame that plays the operator's upper arm on ``side`` (``[frames] <side>_upper_arm``).

    Raises:
        ProfileError: the profile does not name one (seed 004's mimicry needs it).
    """
    key = f"{side}_upper_arm"
    if key not in profile.frames:
        raise ProfileError(f"profile {profile.name}: [frames] lacks {key} (the link that plays the upper arm)")
    return profile.frames[key]
