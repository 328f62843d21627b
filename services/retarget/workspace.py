"""Robot workspace of the wrists and elbows by Monte Carlo (seed 000, section 2.2.1).

The controlled joints are sampled uniformly within their position limits, each
sample goes through Pinocchio forward kinematics, and the target frame positions
form a point cloud per target. The per-axis box ``[U_pmin, U_pmax]`` of that cloud
is what eqs. (1)-(3) map the operator into.

The raw box of a point cloud is dominated by rare extreme configurations (arm
fully stretched along one axis): its faces are barely reachable and its corners
not at all. The paper "moderately shrinks" the workspace to improve accuracy
(section 4.1). Here the shrink is a percentile box: with ``percentile = 0.05``
each axis keeps the 5th..95th percentile of the samples, i.e. the box faces sit
where 95 % of sampled configurations are further inside. An extra ``margin`` [m]
can move every face inward after that. On the G1 the 5-95 % wrist box is about
0.53 x 0.65 x 0.51 m against 0.75 x 0.74 x 0.76 m for the raw one.

Point clouds are cached per robot profile and sampling parameters (the shrink is
applied on load, so changing it needs no resampling) in ``$MIMIC_CACHE_DIR`` or
``~/.cache/mimic``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from shared.mirror import mirror_points, mirrored_arms
from shared.robot.pinocchio_model import RobotModel, build_robot_model
from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile
from shared.targets import TARGET_NAMES

log = logging.getLogger(__name__)

#: Bumped whenever the cached content or its computation changes (2: mirror-pooled clouds, session 21).
CACHE_VERSION = 2
DEFAULT_SAMPLES = 12_000
DEFAULT_PERCENTILE = 0.05


def cache_dir() -> Path:
    """Folder of cached workspaces: ``$MIMIC_CACHE_DIR`` or ``~/.cache/mimic``."""
    env = os.environ.get("MIMIC_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "mimic"


@dataclass(frozen=True)
class Shrink:
    """How the sampled box is restricted.

    Attributes:
        percentile: fraction of samples cut on each side of each axis, in [0, 0.5)
            (0 = raw min/max, 0.05 = 5th..95th percentile box).
        margin: distance every face then moves inward [m], >= 0.
    """

    percentile: float = DEFAULT_PERCENTILE
    margin: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.percentile < 0.5:
            raise ValueError(f"shrink percentile {self.percentile} must be in [0, 0.5)")
        if not self.margin >= 0.0:
            raise ValueError(f"shrink margin {self.margin} m must be >= 0")

    @classmethod
    def parse(cls, text: str | float) -> Shrink:
        """From CLI text: ``"0.05"`` (percentile fraction), ``"0.03m"`` (margin on the raw box),
        or ``"0.05,0.01m"`` (both).

        Raises:
            ValueError: unreadable text, with the accepted forms.
        """
        if isinstance(text, (int, float)):
            return cls(percentile=float(text))
        percentile, margin = None, 0.0
        for part in str(text).replace(" ", "").split(","):
            m = re.fullmatch(r"([0-9]*\.?[0-9]+)(m?)", part)
            if not m:
                raise ValueError(f"shrink {text!r}: expected '0.05' (percentile), '0.03m' (metres) or '0.05,0.01m'")
            if m.group(2):
                margin = float(m.group(1))
            else:
                percentile = float(m.group(1))
        return cls(percentile=0.0 if percentile is None else percentile, margin=margin)

    def to_dict(self) -> dict:
        return {"percentile": self.percentile, "margin": self.margin}


@dataclass
class Workspace:
    """Sampled workspace of each target and its (shrunk) box.

    Attributes:
        points: target -> (n, 3) sampled positions in the robot base frame [m].
        lower, upper: target -> (3,) box [m] after the shrink (``U_pmin``, ``U_pmax``).
        raw_lower, raw_upper: target -> (3,) raw sample min/max [m].
        shrink: the shrink that produced ``lower``/``upper``.
        meta: profile name, samples, seed, joints, cache key.
    """

    points: dict[str, np.ndarray]
    lower: dict[str, np.ndarray] = field(default_factory=dict)
    upper: dict[str, np.ndarray] = field(default_factory=dict)
    raw_lower: dict[str, np.ndarray] = field(default_factory=dict)
    raw_upper: dict[str, np.ndarray] = field(default_factory=dict)
    shrink: Shrink = field(default_factory=Shrink)
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.apply_shrink(self.shrink)

    def apply_shrink(self, shrink: Shrink) -> None:
        """Recompute ``lower``/``upper`` from the samples.

        Raises:
            ValueError: the margin leaves an empty box on some axis.
        """
        self.shrink = shrink
        for name, pts in self.points.items():
            self.raw_lower[name] = pts.min(axis=0)
            self.raw_upper[name] = pts.max(axis=0)
            lo = np.quantile(pts, shrink.percentile, axis=0) + shrink.margin
            hi = np.quantile(pts, 1.0 - shrink.percentile, axis=0) - shrink.margin
            if np.any(hi - lo <= 1e-3):
                raise ValueError(f"shrink {shrink} leaves an empty workspace box for {name}: [{lo}, {hi}]")
            self.lower[name], self.upper[name] = lo, hi

    def contains(self, name: str, p: np.ndarray, tol: float = 1e-9) -> bool:
        """Whether p (3,) [m] lies in the box of target ``name``."""
        return bool(np.all(p >= self.lower[name] - tol) and np.all(p <= self.upper[name] + tol))

    def summary(self) -> dict:
        """JSON-able box per target (rounded to mm)."""
        return {
            n: {"lower": np.round(self.lower[n], 4).tolist(), "upper": np.round(self.upper[n], 4).tolist()}
            for n in self.points
        } | {"shrink": self.shrink.to_dict(), **{k: v for k, v in self.meta.items() if k != "joints"}}


def sample_workspace(
    robot: RobotModel,
    samples: int = DEFAULT_SAMPLES,
    seed: int = 0,
    targets: tuple[str, ...] = TARGET_NAMES,
    progress: bool | None = None,
) -> dict[str, np.ndarray]:
    """Monte Carlo point clouds: uniform joint samples within limits, FK of each target frame.

    Args:
        robot: reduced model; its free joints are the ones sampled, the rest stay at rest.
        samples: number of configurations (the paper uses 12 000).
        seed: RNG seed, so the workspace is reproducible.
        targets: target names whose frame positions are recorded.
        progress: tqdm bar (None = only on a terminal).

    Returns:
        target -> (samples, 3) positions in the robot base frame [m].
    """
    if samples < 100:
        raise ValueError(f"workspace samples {samples} too few (>= 100)")
    rng = np.random.default_rng(seed)
    qs = robot.random_configurations(samples, rng)
    fids = [robot.frame_id(t) for t in targets]
    out = np.empty((len(targets), samples, 3))
    data = robot.model.createData()
    # tqdm's disable=None means "only on a terminal"
    bar = tqdm(qs, desc="workspace FK", unit="q", leave=False, disable=None if progress is None else not progress)
    for i, q in enumerate(bar):
        robot.forward(q, data)
        for k, fid in enumerate(fids):
            out[k, i] = data.oMf[fid].translation
    return {t: out[k] for k, t in enumerate(targets)}


def pool_mirror_images(points: dict[str, np.ndarray], robot: RobotModel) -> bool:
    """Give each arm's clouds the other arm's samples too, mirrored, when the arms are mirror images.

    Why: each arm's cloud is its own Monte Carlo draw, so the two 5-95 % boxes (and the reach radii) differ
    by the sampling noise, and a mirror-image operator got targets 0.2 cm apart from the mirror image of the
    operator's (``mimic eval --mirror``, session 21: wave-left-hand_normal's wrists 0.22 cm on every frame).
    Pooled, the right arm's cloud is exactly the mirror image of the left arm's, from twice the samples.
    Nothing changes for a robot whose arms differ in kinematics or joint ranges
    (:func:`shared.mirror.mirrored_arms`).

    Args:
        points: target -> (n, 3) samples [m] in the base frame, replaced in place by (2n, 3) clouds.

    Returns:
        True when the clouds were pooled.
    """
    if mirrored_arms(robot) is None:
        return False
    for part in ("wrist", "elbow"):
        left, right = f"left_{part}", f"right_{part}"
        if left in points and right in points:
            both = np.vstack([points[left], mirror_points(points[right])])
            points[left], points[right] = both, mirror_points(both)
    return True


def _cache_key(profile: RobotProfile, joints: tuple[str, ...], samples: int, seed: int) -> str:
    h = hashlib.sha256()
    for path in (profile.source, profile.urdf_path):
        if path is not None and Path(path).exists():
            h.update(Path(path).read_bytes())
    h.update(json.dumps([CACHE_VERSION, list(joints), samples, seed, profile.limit_margin, profile.rest]).encode())
    return f"workspace_{profile.name}_{samples}_{seed}_{h.hexdigest()[:12]}"


def load_workspace(
    profile: RobotProfile | str | None = None,
    samples: int = DEFAULT_SAMPLES,
    seed: int = 0,
    with_waist: bool = False,
    shrink: Shrink | None = None,
    use_cache: bool = True,
    robot: RobotModel | None = None,
    progress: bool | None = None,
) -> Workspace:
    """Workspace of the profile's wrists and elbows, from the cache or computed (then cached).

    Args:
        profile: robot profile, name or path (default ``DEFAULT_PROFILE``).
        samples, seed: Monte Carlo parameters.
        with_waist: also sample the waist; by default only the arm joints move (waist at rest),
            because the solver's wrist/elbow boxes should not rely on bending the torso.
        shrink: box restriction (default 5-95 % percentile box).
        use_cache: read/write ``cache_dir()``.
        robot: an already built model matching ``with_waist`` (saves ~0.5 s).
        progress: tqdm bar (None = only on a terminal).
    """
    prof = profile if isinstance(profile, RobotProfile) else load_profile(profile or DEFAULT_PROFILE)
    joints = prof.controlled_joints(with_waist)
    key = _cache_key(prof, joints, samples, seed)
    path = cache_dir() / f"{key}.npz"
    meta = {"profile": prof.name, "samples": samples, "seed": seed, "with_waist": with_waist, "cache_key": key}
    points = _read_cache(path) if use_cache and path.exists() else None
    cached = points is not None
    if points is None:
        if robot is None or tuple(robot.joint_names) != tuple(joints):
            robot = build_robot_model(prof, with_waist=with_waist)
        log.info("computing workspace of %s: %d samples over %d joints", prof.name, samples, len(joints))
        points = sample_workspace(robot, samples, seed, progress=progress)
        pool_mirror_images(points, robot)
        if use_cache:
            _write_cache(path, points)
    # pooled clouds hold both arms' draws (the cache keeps them pooled)
    meta |= {"cached": cached, "mirror_pooled": len(points["left_wrist"]) == 2 * samples}
    return Workspace(points, shrink=shrink or Shrink(), meta=meta)


def _read_cache(path: Path) -> dict[str, np.ndarray] | None:
    """The cached clouds at ``path``, or None (with a warning) when the file cannot be read."""
    try:
        with np.load(path) as z:
            points = {t: z[t] for t in TARGET_NAMES}
    except (OSError, KeyError, ValueError) as exc:
        log.warning("workspace cache %s unreadable (%s); recomputing", path, exc)
        return None
    log.info("workspace loaded from cache %s", path)
    return points


def _write_cache(path: Path, points: dict[str, np.ndarray]) -> None:
    """Cache the clouds at ``path`` atomically (a warning when the folder is not writable)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
        np.savez_compressed(tmp, **points)
        os.replace(tmp, path)
    except OSError as exc:
        log.warning("could not cache workspace at %s: %s", path, exc)
