"""A wheeled-legged robot with an arm (seed 002's TITA-PiPER) from its profile: one MJCF for both libraries.

The profile (``models/tita_piper.toml``) holds the body tree (:mod:`shared.robot.description`),
the seed's frames and the planner's choice of joints. :func:`build_wheeled_robot` loads the
generated MJCF into MuJoCo and into Pinocchio (``pin.buildModelFromMJCF``, free-flyer root),
and extracts the arm's PoE description (screw axes in Σb, home pose of Σa) from Pinocchio.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from shared.kinematics.mobile_arm import MobileArmKinematics
from shared.kinematics.poe import exp6, screw_axis
from shared.paths import MODELS_DIR
from shared.robot.description import Description, load_description, mjcf_path, to_mjcf
from shared.robot.profile import ProfileError


@dataclass(frozen=True)
class WheeledProfile:
    """Profile of a wheeled-legged arm robot.

    Attributes:
        name, source: profile name and TOML path. mjcf: generated MJCF path.
        description: the body tree.
        torso_site, hand_site: MJCF sites of Σb and Σa. wheels: the two wheel bodies (left, right).
        arm: the planner's three arm joints (J1 yaw, J2 and J3 pitch). held: other arm joints -> angle [rad].
        z_range: torso-centre height range [m]. start_base (4,) [x, y, z, α], start_arm (3,) [rad].
        retarget: the profile's ``[retarget]`` table as written (read by
            :mod:`services.retarget.mobile`, which checks it); empty when absent.
    """

    name: str
    source: Path
    mjcf: Path
    description: Description
    torso_site: str
    hand_site: str
    wheels: tuple[str, str]
    arm: tuple[str, str, str]
    held: dict[str, float]
    z_range: tuple[float, float]
    start_base: np.ndarray
    start_arm: np.ndarray
    retarget: dict = field(default_factory=dict)

    @property
    def arm_chain(self) -> tuple[str, ...]:
        """Every arm joint from the torso to the hand: the planner's three, then the held ones."""
        return (*self.arm, *self.held)

    def joint_range(self, name: str) -> tuple[float, float]:
        """(lower, upper) of a joint [rad] from the description."""
        for j in self.description.joints:
            if j.name == name and j.range is not None:
                return j.range
        raise KeyError(f"joint {name!r} has no range in {self.source}")


#: ``kind`` of the profiles this module reads.
WHEELED_KIND = "wheeled_legged_arm"


def is_wheeled_profile(name_or_path: str | Path) -> bool:
    """True when the profile (name or path) exists and declares ``kind = "wheeled_legged_arm"``."""
    path = Path(name_or_path)
    if not path.suffix:
        path = MODELS_DIR / f"{name_or_path}.toml"
    if not path.exists():
        return False
    with path.open("rb") as fh:
        return tomllib.load(fh).get("kind") == WHEELED_KIND


def load_wheeled_profile(name_or_path: str | Path) -> WheeledProfile:
    """Load a wheeled-arm profile by name (``models/<name>.toml``) or path.

    Raises:
        ProfileError: missing file or fields, or a stale generated MJCF.
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = MODELS_DIR / f"{name_or_path}.toml"
    if not path.exists():
        raise ProfileError(f"robot profile {str(name_or_path)!r} not found")
    with path.open("rb") as fh:
        raw = tomllib.load(fh)
    try:
        frames, plan = raw["frames"], raw["planner"]
        desc = load_description(path)
        mjcf = mjcf_path(path)
        prof = WheeledProfile(
            name=raw.get("name", path.stem),
            source=path,
            mjcf=mjcf,
            description=desc,
            torso_site=frames["torso"],
            hand_site=frames["hand"],
            wheels=tuple(frames["wheels"]),
            arm=tuple(plan["arm"]),
            held={k: float(v) for k, v in plan.get("held", {}).items()},
            z_range=tuple(float(v) for v in plan["z_range"]),
            start_base=np.array(plan["start_base"], dtype=float),
            start_arm=np.array(plan["start_arm"], dtype=float),
            retarget=dict(raw.get("retarget", {})),
        )
    except KeyError as exc:
        raise ProfileError(f"{path}: missing field {exc}") from None
    if len(prof.arm) != 3 or len(prof.wheels) != 2:
        raise ProfileError(f"{path}: [planner] arm needs 3 joints and [frames] wheels 2 bodies")
    if not mjcf.exists() or mjcf.read_text() != to_mjcf(desc):
        raise ProfileError(f"{mjcf} is missing or stale: run python -m shared.robot.description {path}")
    return prof


@dataclass
class WheeledRobot:
    """The same MJCF compiled by MuJoCo and loaded by Pinocchio, plus the arm's PoE kinematics.

    Attributes:
        mj_model: MuJoCo model (free root, motors on every joint, floor).
        pin_model: Pinocchio model (free-flyer root; q = [p (3), quat xyzw (4), joints]).
        kin: the planner's hand kinematics (arm screws in Σb at the held wrist angles).
        S_chain, M_chain: (6, k) screws and (4, 4) home pose of the whole arm chain (all arm joints).
    """

    profile: WheeledProfile
    mj_model: mujoco.MjModel
    pin_model: pin.Model
    kin: MobileArmKinematics
    S_chain: np.ndarray
    M_chain: np.ndarray


def arm_screws(model: pin.Model, joints: tuple[str, ...], frame: str, base_frame: str) -> tuple[np.ndarray, np.ndarray]:
    """Space screw axes S (6, k) of ``joints`` and home pose M (4, 4) of ``frame``, both in ``base_frame``.

    Read off Pinocchio at the neutral configuration: each revolute joint's axis (from its
    motion subspace) and origin give ``S_i = [ŝ; -ŝ × q]``; a prismatic joint gives ``[0; v̂]``.
    """
    data = model.createData()
    q0 = pin.neutral(model)
    pin.forwardKinematics(model, data, q0)
    pin.updateFramePlacements(model, data)
    oMb = data.oMf[model.getFrameId(base_frame)]
    bMo = oMb.inverse()
    S = np.zeros((6, len(joints)))
    for i, name in enumerate(joints):
        jid = model.getJointId(name)
        if jid >= model.njoints:
            raise KeyError(f"joint {name!r} not in the model")
        # Motion subspace of a 1-DoF joint in its own frame, [v; ω] (Pinocchio order).
        Sj = _joint_motion(model, jid)
        bMi = bMo * data.oMi[jid]
        axis_local, lin_local = Sj[3:], Sj[:3]
        if np.linalg.norm(axis_local) > 0:
            S[:, i] = screw_axis(bMi.rotation @ axis_local, bMi.translation)
        else:
            S[3:, i] = bMi.rotation @ lin_local
    M = (bMo * data.oMf[model.getFrameId(frame)]).homogeneous
    return S, M


def _joint_motion(model: pin.Model, jid: int) -> np.ndarray:
    """(6,) motion subspace [v; ω] of a 1-DoF joint, in its joint frame (from a unit-velocity Jacobian)."""
    data = model.createData()
    q = pin.neutral(model)
    J = pin.computeJointJacobian(model, data, q, jid)  # LOCAL frame of the joint
    col = model.joints[jid].idx_v
    return J[:, col]


def build_wheeled_robot(profile: WheeledProfile | str | Path = "tita_piper") -> WheeledRobot:
    """Compile the profile's MJCF with MuJoCo and Pinocchio, and extract the arm's PoE kinematics."""
    prof = profile if isinstance(profile, WheeledProfile) else load_wheeled_profile(profile)
    mj_model = mujoco.MjModel.from_xml_path(str(prof.mjcf))
    pin_model = pin.buildModelFromMJCF(str(prof.mjcf))  # the <freejoint> becomes a free flyer
    S_chain, M_chain = arm_screws(pin_model, prof.arm_chain, prof.hand_site, prof.torso_site)
    # Fold the held joints into the planner's home pose: M = e^[S4]θ4 ... M_chain.
    M = np.eye(4)
    for k, name in enumerate(prof.held):
        M = M @ exp6(S_chain[:, 3 + k] * prof.held[name])
    kin = MobileArmKinematics(S_chain[:, :3].copy(), M @ M_chain)
    return WheeledRobot(prof, mj_model, pin_model, kin, S_chain, M_chain)


def planner_limits(robot: WheeledRobot) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) (7,) of seed 002's coordinates: x, y, α unbounded; z and the arm from the profile."""
    prof = robot.profile
    lo = np.full(7, -np.inf)
    hi = np.full(7, np.inf)
    lo[2], hi[2] = prof.z_range
    for k, name in enumerate(prof.arm):
        lo[4 + k], hi[4 + k] = prof.joint_range(name)
    return lo, hi
