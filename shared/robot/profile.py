"""Robot profiles: a robot is a TOML file under ``models/``, not code."""

from __future__ import annotations

import math
import re
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
class CollisionSpec:
    """Which links must keep clear of which, read from the profile's ``[collision]`` table.

    Attributes:
        groups: group name -> robot links (URDF link names) whose collision geometry it holds.
        pairs: (group, group) pairs whose links are kept apart; every link of one against every link
            of the other.
        safety_distance: d_s [m], the distance a pair never comes closer than.
        influence_distance: d_i [m] (> d_s), below which a pair's approach speed is limited.
        damper_speed: xi [m/s], the approach speed allowed at d_i; it falls linearly to 0 at d_s.
        braking_distance: d_b [m] (d_s <= d_b < d_i; default d_s), where the braking allowance ends.
        braking_deceleration: a [m/s^2]: farther than d_b a pair may also approach as fast as it could still
            brake from, at a, before d_b (``sqrt(2 a (d - d_b))``, when that is more than the linear damper's);
            0 = the linear damper alone.
    """

    groups: dict[str, tuple[str, ...]]
    pairs: tuple[tuple[str, str], ...]
    safety_distance: float = 0.015
    influence_distance: float = 0.08
    damper_speed: float = 1.0
    braking_distance: float = 0.015
    braking_deceleration: float = 0.0


@dataclass(frozen=True)
class RobotProfile:
    """Everything the services need to know about one robot.

    Attributes:
        name: profile name. urdf_path: absolute URDF path.
        package_dirs: folders that ``package://`` URIs are resolved against.
        base_frame: frame all targets are expressed in.
        waist: waist joints in solver order (may be empty: an arms-only robot).
        arms: side (``left``/``right``) -> the arm's joint roles.
        frames: target name (``left_wrist``, ...; at least every ``TARGET_NAMES``) -> robot frame: its
            origin is the target's position, and its orientation the target's unless ``orientation_frames``
            names another frame.
        orientation_frames: target name -> the robot frame whose orientation is the target's (the profile's
            ``[orientation_frames]``, optional; a target without an entry takes both from ``frames``). Why a
            second frame: a robot wrist whose axes do not meet has no point that all three wrist joints leave in
            place and that turns with the hand (the G1's yaw axis sits 4.6 cm past its pitch axis).
        human: target name -> canonical human bone.
        rest: joint name -> rest angle [rad] (unlisted joints rest at 0).
        max_joint_velocity: cap on every joint speed [rad/s].
        joint_velocities: joint -> a lower speed cap of its own [rad/s] (the profile's ``[velocity_limits]``,
            optional): a joint's limit is the smallest of its URDF limit, ``max_joint_velocity`` and this entry.
        max_joint_acceleration: cap on every joint acceleration [rad/s^2].
        joint_accelerations: joint -> acceleration limit [rad/s^2] its motor can deliver (the
            profile's ``[acceleration_limits]``, derived by ``python -m shared.robot.accel_limits``).
        motor_acceleration_limits: ``[model] motor_acceleration_limits``: when true, a joint's
            limit is the smaller of its ``joint_accelerations`` entry and ``max_joint_acceleration``;
            when false the table is data only and every joint has the global cap.
        limit_margin: shrink of each position limit [rad].
        actuators: MuJoCo servo parameters (kp, kv, armature).
        arms_out: joint -> offset [rad] from rest holding the arms clear of the body (centre
            of the servo tracking sine).
        collision: self-collision pairs the solver keeps apart (None: the profile has no
            ``[collision]`` table, no self-collision avoidance).
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
    joint_accelerations: dict[str, float] = field(default_factory=dict)
    joint_velocities: dict[str, float] = field(default_factory=dict)
    motor_acceleration_limits: bool = False
    source: Path | None = None
    collision: CollisionSpec | None = None
    orientation_frames: dict[str, str] = field(default_factory=dict)

    def orientation_frame(self, target: str) -> str:
        """Robot frame whose orientation is ``target``'s: its ``[orientation_frames]`` entry, else its ``[frames]``
        one."""
        return self.orientation_frames.get(target, self.frames[target])

    @property
    def split_orientation_frames(self) -> dict[str, str]:
        """Target -> orientation frame, for the targets whose orientation frame is not their ``[frames]`` one."""
        return {t: f for t, f in self.orientation_frames.items() if f != self.frames[t]}

    def controlled_joints(self, with_waist: bool = True) -> tuple[str, ...]:
        """Controlled joints in solver order: waist (if asked) then each arm in ``SIDES`` order.

        (17,) with the waist, (14,) without on the G1.
        """
        return (self.waist if with_waist else ()) + tuple(j for s in SIDES for j in self.arms[s].joints)

    def joint_velocity(self, joint: str) -> float:
        """Speed cap of ``joint`` [rad/s]: its ``[velocity_limits]`` entry, if any, capped by ``max_joint_velocity``
        (the URDF's own limit applies on top, in ``build_robot_model``)."""
        return min(self.joint_velocities.get(joint, math.inf), self.max_joint_velocity)

    def joint_acceleration(self, joint: str) -> float:
        """Acceleration limit of ``joint`` [rad/s^2]: with ``motor_acceleration_limits``, its
        ``[acceleration_limits]`` entry capped by ``max_joint_acceleration``; otherwise (or for a joint
        without an entry) the global cap alone."""
        if not self.motor_acceleration_limits:
            return self.max_joint_acceleration
        return min(self.joint_accelerations.get(joint, math.inf), self.max_joint_acceleration)

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
            joint_accelerations={
                k: _number(raw["acceleration_limits"], k, "[acceleration_limits]")
                for k in raw.get("acceleration_limits", {})
            },
            joint_velocities={
                k: _number(raw["velocity_limits"], k, "[velocity_limits]") for k in raw.get("velocity_limits", {})
            },
            motor_acceleration_limits=_flag(model, "motor_acceleration_limits", "[model]"),
            source=path,
            collision=_collision(raw["collision"], path) if "collision" in raw else None,
            orientation_frames={str(k): str(v) for k, v in raw.get("orientation_frames", {}).items()},
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


def _flag(table: dict, key: str, where: str) -> bool:
    """``table[key]`` as a bool (false when missing); raises ValueError naming it when not a bool."""
    value = table.get(key, False)
    if not isinstance(value, bool):
        raise ValueError(f"{where} {key} must be true or false, got {value!r}")
    return value


def _arm(raw: dict, where: str, path: Path) -> ArmJoints:
    joints = tuple(raw["joints"])
    elbow = raw["elbow"]
    if elbow not in joints:
        raise ProfileError(f"{path}: {where} elbow {elbow!r} is not one of its joints {list(joints)}")
    return ArmJoints(joints, elbow)


def _collision(raw: dict, path: Path) -> CollisionSpec:
    """The ``[collision]`` table: groups of links, pairs of groups, damper distances and speed."""
    groups = {str(k): tuple(str(x) for x in v) for k, v in raw["groups"].items()}
    pairs = []
    for pair in raw["pairs"]:
        if len(pair) != 2 or any(g not in groups for g in pair):
            raise ProfileError(f"{path}: [collision] pair {pair!r} must name two of the groups {sorted(groups)}")
        pairs.append((str(pair[0]), str(pair[1])))
    d_s = _number(raw, "safety_distance", "[collision]", CollisionSpec.safety_distance)
    spec = CollisionSpec(
        groups,
        tuple(pairs),
        d_s,
        _number(raw, "influence_distance", "[collision]", CollisionSpec.influence_distance),
        _number(raw, "damper_speed", "[collision]", CollisionSpec.damper_speed),
        _number(raw, "braking_distance", "[collision]", d_s),
        _number(raw, "braking_deceleration", "[collision]", CollisionSpec.braking_deceleration),
    )
    if not 0.0 <= spec.safety_distance < spec.influence_distance or not spec.damper_speed > 0.0:
        raise ProfileError(
            f"{path}: [collision] needs 0 <= safety_distance < influence_distance and damper_speed > 0, got "
            f"{spec.safety_distance}, {spec.influence_distance}, {spec.damper_speed}"
        )
    if not spec.safety_distance <= spec.braking_distance < spec.influence_distance or spec.braking_deceleration < 0:
        raise ProfileError(
            f"{path}: [collision] needs safety_distance <= braking_distance < influence_distance and "
            f"braking_deceleration >= 0, got {spec.braking_distance}, {spec.braking_deceleration}"
        )
    return spec


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
    # Entries for joints the profile does not control are allowed (a variant that drops the waist keeps
    # the table), but each must be a joint of the URDF: a typo must not silently leave a joint uncapped.
    urdf = prof.urdf_path.read_text()
    urdf_joints = set(re.findall(r'<joint\s[^>]*?name="([^"]+)"', urdf))
    for table, limits in (
        ("acceleration_limits", prof.joint_accelerations),
        ("velocity_limits", prof.joint_velocities),
    ):
        unknown = sorted(set(limits) - urdf_joints)
        if unknown:
            raise ProfileError(f"{path}: [{table}] names joints that are not in the URDF: {unknown}")
        for joint, v in limits.items():
            if not (math.isfinite(v) and v > 0.0):
                raise ProfileError(f"{path}: [{table}] {joint} must be a positive number, got {v}")
    if prof.motor_acceleration_limits and not prof.joint_accelerations:
        raise ProfileError(f"{path}: [model] motor_acceleration_limits = true needs an [acceleration_limits] table")
    unknown = sorted(set(prof.orientation_frames) - set(prof.frames))
    if unknown:
        raise ProfileError(f"{path}: [orientation_frames] names targets that are not in [frames]: {unknown}")
    links = set(re.findall(r'<link\s[^>]*?name="([^"]+)"', urdf))
    unknown = sorted(f for f in prof.orientation_frames.values() if f not in links)
    if unknown:
        raise ProfileError(f"{path}: [orientation_frames] names links that are not in the URDF: {unknown}")


def upper_arm_frame(profile: RobotProfile, side: str) -> str:
    """Robot frame that plays the operator's upper arm on ``side`` (``[frames] <side>_upper_arm``).

    Raises:
        ProfileError: the profile does not name one (seed 004's mimicry needs it).
    """
    key = f"{side}_upper_arm"
    if key not in profile.frames:
        raise ProfileError(f"profile {profile.name}: [frames] lacks {key} (the link that plays the upper arm)")
    return profile.frames[key]
