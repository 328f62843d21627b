"""Robot profiles: a robot is a TOML file under ``models/``, not code."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
MODELS_DIR = REPO_ROOT / "models"
DEFAULT_PROFILE = "g1_29dof"
TARGET_FRAMES = ("left_wrist", "right_wrist", "left_elbow", "right_elbow")


class ProfileError(ValueError):
    """A robot profile that cannot be used; the message says why."""


@dataclass(frozen=True)
class RobotProfile:
    """Everything the services need to know about one robot.

    Attributes:
        name: profile name. urdf_path: absolute URDF path.
        package_dirs: folders that ``package://`` URIs are resolved against.
        base_frame: frame all targets are expressed in.
        waist, left_arm, right_arm: controlled joint names, in solver order.
        frames: target name (``left_wrist``, ...) -> robot frame name.
        human: target name -> canonical human bone.
        rest: joint name -> rest angle [rad] (unlisted joints rest at 0).
        max_joint_velocity: cap on every joint speed [rad/s].
        max_joint_acceleration: cap on every joint acceleration [rad/s^2].
        limit_margin: shrink of each position limit [rad].
        actuators: MuJoCo servo parameters (kp, kv, armature).
    """

    name: str
    urdf_path: Path
    package_dirs: tuple[Path, ...]
    base_frame: str
    waist: tuple[str, ...]
    left_arm: tuple[str, ...]
    right_arm: tuple[str, ...]
    frames: dict[str, str]
    human: dict[str, str]
    rest: dict[str, float]
    max_joint_velocity: float
    max_joint_acceleration: float
    limit_margin: float
    actuators: dict[str, float] = field(default_factory=dict)
    source: Path | None = None

    def controlled_joints(self, with_waist: bool = True) -> tuple[str, ...]:
        """Controlled joints in solver order: (17,) with the waist, (14,) without."""
        return (self.waist if with_waist else ()) + self.left_arm + self.right_arm

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
        human = dict(raw.get("human", {t: t for t in TARGET_FRAMES}))
        prof = RobotProfile(
            name=raw.get("name", path.stem),
            urdf_path=urdf_path,
            package_dirs=(package_root,),
            base_frame=model["base_frame"],
            waist=tuple(model.get("waist", ())),
            left_arm=tuple(model["left_arm"]),
            right_arm=tuple(model["right_arm"]),
            frames=frames,
            human=human,
            rest={k: float(v) for k, v in raw.get("rest", {}).items()},
            max_joint_velocity=float(model.get("max_joint_velocity", 3.0)),
            max_joint_acceleration=float(model["max_joint_acceleration"]),
            limit_margin=float(model.get("limit_margin", 0.0)),
            actuators={k: float(v) for k, v in raw.get("actuators", {}).items()},
            source=path,
        )
    except KeyError as exc:
        raise ProfileError(f"{path}: missing field {exc}") from None
    if not prof.urdf_path.exists():
        raise ProfileError(f"{path}: URDF {prof.urdf_path} does not exist")
    missing = [t for t in TARGET_FRAMES if t not in prof.frames]
    if missing:
        raise ProfileError(f"{path}: [frames] lacks {missing}")
    return prof
