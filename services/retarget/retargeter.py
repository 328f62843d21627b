"""The retarget service's pure logic: ``Retargeter.step(HumanFrame) -> TaskTargets | None``.

Per frame and per target (both wrists and elbows):

1. the source bone (robot profile ``[human]`` table) position goes through the
   mapping of the configured mode into the robot base frame: "reach" (default,
   :mod:`.reach`: the wrist per direction from the shoulder onto the robot's sampled
   reachable set) or the per-axis maps of :mod:`.mapping` (eqs. 1-3 "paper", "bounded",
   or "incremental");
2. its orientation goes through eq. (4) (:mod:`.orientation`); elbows carry it with
   ``use_rotation=False`` unless configured;
3. with ``wrist_range``, each wrist orientation is clipped into the wrist joints' ranges relative to the
   forearm its elbow and wrist targets imply (:mod:`.wrist_range`);
4. with ``trunk_clearance`` (default), each wrist target that would put the robot hand within the collision
   safety distance of its trunk (waist at rest) is pushed out to it, and its swivel elbow placed again
   (:mod:`.trunk`);
5. with ``consistent_targets``, per arm the elbow position and the wrist orientation become those
   of the arm posture that meets the wrist position and comes closest to both (:mod:`.consistent`);
6. linear and angular velocities are finite differences with the previous frame,
   low-pass filtered (:mod:`.velocity`);
7. a target whose bone is missing or invalid is published ``valid=False`` holding its
   last valid pose (the robot rest pose before any) with zero velocity.

Each frame with a measured chest orientation also publishes ``TaskTargets.waist``: the robot's waist angles for
the operator's chest rotation relative to the pelvis since the calibration frame (:mod:`.torso`).

Frame order is judged by :class:`shared.sequence.SequenceGuard` (the same rule as the
ingest sanitizer's): frames whose ``seq`` or ``stamp`` does not increase are rejected
(``step`` returns None and ``last_reject`` says why); a seq far back, or ``resync_after``
consecutive rejects, is a restarted source (e.g. a replayed clip), followed again.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import asdict, dataclass, field

import numpy as np

from services.retarget.calibration import (
    DEFAULT_ARM_LENGTH,
    Calibration,
    anthropometric,
    from_wrists,
)
from services.retarget.consistent import ConsistentArm
from services.retarget.elbow import ArmGeometry, human_swivel, swivel_direction
from services.retarget.intake import FrameIntake
from services.retarget.mapping import ELBOW_PLACEMENTS, MODES, ORIENTATION_REFERENCES, AbsoluteMap, IncrementalMap
from services.retarget.orientation import (
    ForearmOrientationMap,
    OrientationMap,
    angular_velocity,
    arm_alignment,
    calibration_orientations,
)
from services.retarget.reach import REACH_SAMPLES, ReachMap, operator_reach
from services.retarget.torso import WaistMap, chest_rotation
from services.retarget.trunk import FAST_CLEARANCE, HandSpeed, NoTrunkError, TrunkClearance
from services.retarget.upper_arm import UpperArmSolver
from services.retarget.velocity import LowPassVelocity
from services.retarget.workspace import DEFAULT_SAMPLES, Shrink, Workspace, load_workspace
from services.retarget.wrist_range import WristRange
from shared.messages import Bone, Header, HumanFrame, Target, TaskTargets
from shared.robot.pinocchio_model import RobotModel, build_robot_model
from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile
from shared.robot.profile import upper_arm_frame as upper_arm_link
from shared.rotations import matrices_to_quats, matrix_to_quat, quat_to_matrix, quats_to_matrices
from shared.sequence import SequenceGuard
from shared.targets import ELBOWS, SIDES, TARGET_NAMES, WRISTS, elbow_of, side_of, wrist_of
from shared.wrist_only import is_wrist_only

log = logging.getLogger(__name__)

#: Source names whose frames are counted in ``sources_seen`` (a bound against a flood of names).
MAX_SOURCES = 32
#: What a source must send before it is retargeted (said with every ``uncalibrated`` reject).
CALIBRATION_HINT = (
    "auto-calibration takes the first frame with shoulder, elbow and wrist of both arms, arms hanging at rest "
    "(one arm alone is accepted after 30 frames and mirrored); otherwise install one with "
    "`mimic calibrate --file FILE` or start retarget with --calibration FILE; a wrist-only source (wrists, no "
    "shoulders or elbows) calibrates from its first rest frame with an assumed arm length (retarget --arm-length)"
)


@dataclass
class RetargetConfig:
    """Retarget configuration (all fields settable from the CLI or a config file).

    Attributes:
        mode: "bounded" (default: eqs. 1-3 per axis, clamped to the box), "reach" (the wrist per
            direction from the shoulder, the operator's reach ratio onto the robot's sampled reach in
            that direction), "paper" (eqs. 1-3 literally) or "incremental".
        reach_samples: Monte Carlo samples of the reach map ("reach" mode; more than the box needs,
            since each direction of the sphere gets its own estimate).
        robot: robot profile name or path.
        samples, seed: Monte Carlo workspace sampling (paper: 12 000 samples).
        with_waist: sample the waist joints too (default: arms only, waist at rest).
        shrink: workspace restriction (default 5-95 % percentile box).
        incremental_scale: scale k [-] of the incremental mapping U += k dH (a ratio, not a gain [1/s]).
        velocity_tau: velocity low-pass time constant [s] (0 = raw differences). The solver extrapolates
            each target with this velocity until the next frame, so a slow filter is lag: on the 23 BVH
            and 2 C3D clips (``mimic eval --velocity-tau``, hqp-nullspace) 0.01 against 0.05 lowered the
            wrist frame error (the robot against each frame at its instant) on every clip, 0.83 -> 0.56 cm
            mean, and the commanded jerk 85 -> 79 krad/s^3; 0 raised the jerk on the 100+ Hz marker
            clip by a third (its marker noise), 0.01 did not.
        max_gap: frame gap [s] above which velocities restart from zero.
        elbow_rotation: publish elbow orientations with use_rotation=True.
        resync_after: consecutive non-increasing frames after which the source counts as restarted.
        auto_calibrate: without a calibration, calibrate anthropometrically from the first frame
            whose arm bones are all valid (the operator must start at rest, arms hanging).
        one_arm_after: auto-calibration frames with only one valid arm to skip before accepting one
            (the other arm is then mirrored; one-armed marker sets never show both).
        elbow_placement: "mapped" (the paper): eqs. (1)-(3) per axis like the wrist, so the
            wrist-elbow target distance follows the operator's forearm (0.10-0.15 m on the real clips),
            not the robot's (0.18 m): not reachable together. "swivel" (default): elbow targets
            at the robot's own arm lengths from its shoulder and the wrist target, on the side the
            operator's elbow points to (:mod:`.elbow`). Incremental mode always maps elbows.
        orientation_reference: the robot orientation ``W_R_U`` that eq. (4) pairs with the operator's
            calibration orientation. "rest" (the paper read literally): the profile rest
            pose (G1: elbows bent 1.2 rad), which is not the pose the operator calibrates in (arms
            hanging, elbows nearly straight), so every orientation target carries that difference
            (40-60 deg of wrist pitch and roll). "posture": the robot's own posture
            for the calibration targets (:func:`.orientation.calibration_posture`, wrist joints at
            zero), so the operator's calibration pose maps onto a pose the robot takes. "forearm"
            (default): as "posture", and the wrist orientation follows the hand *relative to the forearm*
            (:class:`.orientation.ForearmOrientationMap`; needs ``elbow_placement="swivel"``, else it
            acts as "posture"). ``mimic retarget --elbow-placement mapped --orientation-reference rest``
            reproduces the paper.
        source: the frame ``source`` to follow when several publish at once ("" = the first one
            seen, until it is silent for ``source_timeout``); frames of the others are rejected as
            ``other_source`` and each new one is named once in the log.
        source_timeout: silence of the followed source [s] (frame ``t0`` clock) after which
            another source is followed (only without ``source``).
        arm_length: operator arm length, shoulder to wrist [m], for sources without arm bones
            (wrist-only: VR controllers); they calibrate with :func:`.calibration.from_wrists`.
        upper_arms: publish ``TaskTargets.upper_arms`` (seed 004's operator upper-arm orientation
            ``R_m`` in the robot frame) for every arm whose shoulder, elbow and wrist are valid
            (needs ``elbow_placement="swivel"``). Off by default: its per-frame IK costs ~2 ms per
            frame (step p50 2.8 against 0.84 ms on byebye_happy), and only ``clik-mimicry`` and the
            posture-policy training read it; ``mimic retarget --upper-arms`` turns it on.
        consistent_targets: per frame and arm, publish the elbow position and the wrist orientation of
            the arm posture (waist at rest, within the joint ranges) that meets the wrist target and comes
            closest to the mapped elbow and wrist orientation (``consistent.py``), so the three targets
            are reachable together; the wrist position stays the mapped one. Arms without a valid
            elbow (wrist-only sources) are left as mapped.
        wrist_range: clip each wrist orientation target into the wrist joints' ranges (less the solver's
            headroom), relative to the robot forearm that its elbow and wrist targets imply
            (:mod:`.wrist_range`; needs ``elbow_placement="swivel"``), so the hand never asks for a wrist
            angle past a stop. Off by default: see the retarget README for the measurement.
        forearm_blend: with ``orientation_reference="forearm"``, fade the forearm frames' rotation about the
            forearm in and out as either arm straightens (:func:`.orientation.arm_alignment`), instead of
            the switch at ``STRAIGHT_SIN`` (a jump of up to ~18 deg per frame in the wrist target). Off by
            default: at 30 fps the arms cross the blend's band within one frame, so it hardly lowers the step at
            the switch frames (byebye_happy 14.1 -> 13.2 deg), and on by default it moved the vigorous clips'
            targets enough that the numpy reference HQP dropped a level once (``test_degenerate_levels``).
        trunk_clearance: keep every wrist target's robot hand (posed at the target) outside the robot's trunk at
            the waist's rest posture by the profile's collision safety distance plus 5 mm, pushed out from the
            axis of the trunk body (the surface normal on the torso's front; :mod:`.trunk`); the swivel elbow is
            then placed for the pushed wrist. On by default since session 13, for profiles with a ``[collision]``
            table (like the solver's self-collision avoidance). Without it a hand resting on the operator's belly
            is inside the G1's thicker trunk, and a strict HQP with self-collision avoidance reaches it by turning
            the waist (call_normal_001: yaw -40 deg, the elbow 14 cm off). 25 clips (``mimic eval <23 BVH> <2 C3D>
            --algos hqp-nullspace,wqp,mink --no-sim [--no-trunk-clearance]``): wrist targets reachable on
            >= 99.5 % of the frames on 25 clips (16 without), HQP elbow mean 1.85 -> 1.67 cm over the clips
            (bow_old 2.00 -> 0.07, call_normal_001 2.48 -> 0.62), wrist 0.215 -> 0.217; the cost is kick_normal's
            right hand, 2.5 cm inside the chest and slow, now published 4.6 cm in front of it (wrist 0.45 ->
            0.56 cm). See the retarget README.
        trunk_clearance_fast: [m] with ``trunk_clearance``, the clearance kept for a hand moving faster than
            :data:`.trunk.FAST` (low-passed speed of the mapped wrist target; the full clearance below
            :data:`.trunk.SLOW`, a smoothstep between); None: the full clearance at every speed (run_happy's
            elbow 10.1 -> 11.4 cm instead of 10.3: a swinging arm's targets pushed out of the rest trunk by 2 cm
            are ones it no longer reaches).
    """

    mode: str = MODES[0]
    robot: str = DEFAULT_PROFILE
    samples: int = DEFAULT_SAMPLES
    reach_samples: int = REACH_SAMPLES
    seed: int = 0
    with_waist: bool = False
    shrink: Shrink = field(default_factory=Shrink)
    incremental_scale: float = 1.0
    velocity_tau: float = 0.01
    max_gap: float = 0.5
    elbow_rotation: bool = False
    resync_after: int = 30
    auto_calibrate: bool = True
    one_arm_after: int = 30
    elbow_placement: str = ELBOW_PLACEMENTS[0]
    orientation_reference: str = ORIENTATION_REFERENCES[0]
    source: str = ""
    source_timeout: float = 1.0
    arm_length: float = DEFAULT_ARM_LENGTH
    upper_arms: bool = False
    consistent_targets: bool = False
    wrist_range: bool = False
    forearm_blend: bool = False
    trunk_clearance: bool = True
    trunk_clearance_fast: float | None = FAST_CLEARANCE

    def __post_init__(self) -> None:
        if self.elbow_placement not in ELBOW_PLACEMENTS:
            raise ValueError(f"elbow placement {self.elbow_placement!r}; known: {list(ELBOW_PLACEMENTS)}")
        if self.orientation_reference not in ORIENTATION_REFERENCES:
            raise ValueError(
                f"orientation reference {self.orientation_reference!r}; known: {list(ORIENTATION_REFERENCES)}"
            )
        if self.mode not in MODES:
            raise ValueError(f"retarget mode {self.mode!r}; known: {list(MODES)}")
        if not self.incremental_scale > 0:
            raise ValueError(f"incremental_scale {self.incremental_scale} must be > 0")
        if self.resync_after < 1:
            raise ValueError(f"resync_after {self.resync_after} must be >= 1")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["shrink"] = self.shrink.to_dict()
        return d


#: Placements of a pushed wrist's elbow, each followed by a push along the forearm it gives, but the last: the
#: forearm turns the hand (:class:`.trunk.HandChain`), so the first push's clearance held only to ~1 mm on the
#: elbow placed after it (call_normal_001: median 1.89 cm against 2.0).
TRUNK_PASSES = 3


def _waist_map(prof: RobotProfile) -> WaistMap | None:
    """The profile's operator-to-waist map, None (logged) when its waist is not three orthogonal joints."""
    if not prof.waist:
        return None
    try:
        return WaistMap(profile=prof)
    except ValueError as exc:
        log.warning("no operator waist published: %s", exc)
        return None


class Retargeter(FrameIntake):
    """HumanFrames in the operator pelvis frame -> wrist/elbow TaskTargets in the robot base frame.

    Args:
        config: see :class:`RetargetConfig`.
        calibration: operator calibration; None = auto-calibrate (if configured) on the first usable frame.
        workspace: robot workspace; None = load (cached) per the config.
        robot: reduced robot model; None = build from the config.
    """

    def __init__(
        self,
        config: RetargetConfig | None = None,
        calibration: Calibration | None = None,
        workspace: Workspace | None = None,
        robot: RobotModel | None = None,
    ):
        self.config = config or RetargetConfig()
        prof = robot.profile if robot is not None else load_profile(self.config.robot)
        self.profile: RobotProfile = prof
        self.robot = robot or build_robot_model(prof, with_waist=self.config.with_waist)
        self.workspace = workspace or load_workspace(
            prof,
            self.config.samples,
            self.config.seed,
            self.config.with_waist,
            self.config.shrink,
            robot=self.robot,
        )
        #: target -> source human bone
        self.bone_of = {t: prof.human.get(t, t) for t in TARGET_NAMES}
        rest = self.robot.frame_poses(self.robot.q_rest, names=TARGET_NAMES)
        #: target -> (p (3,), R (3, 3)) robot rest pose in the base frame
        self.robot_rest = {t: (rest[t][0].copy(), rest[t][1].copy()) for t in TARGET_NAMES}
        reach = self.config.mode == "reach"
        #: side -> robot arm geometry for the swivel elbow placement and the reach map
        self.arms = ArmGeometry.measure_arms(self.robot) if self.config.elbow_placement == "swivel" or reach else {}
        #: side -> reachable radii per direction from the shoulder ("reach" mode)
        self.reach: dict[str, ReachMap] = {}
        if reach:
            cloud = load_workspace(
                prof, self.config.reach_samples, self.config.seed, self.config.with_waist, robot=self.robot
            )
            left = ReachMap.cached(cloud, "left", self.arms["left"].centre)
            if cloud.meta["mirror_pooled"]:  # arms that mirror each other get mirror-image maps
                right = left.mirrored()
            else:
                right = ReachMap.cached(cloud, "right", self.arms["right"].centre)
            self.reach = {"left": left, "right": right}
        #: side -> the operator's upper arm as the robot's upper-arm link orientation (seed 004 eq. 6)
        self.upper_arm_maps: dict[str, UpperArmSolver] = {}
        if self.config.upper_arms and self.arms:
            for side in self.arms:
                self.upper_arm_maps[side] = UpperArmSolver(self.robot, side, upper_arm_link(prof, side))
        #: side -> the posture IK that makes the arm's published targets reachable together
        self.consistent: dict[str, ConsistentArm] = (
            {s: ConsistentArm(self.robot, s) for s in SIDES} if self.config.consistent_targets else {}
        )
        #: side -> the projection of the wrist orientation into the wrist joints' ranges (``wrist_range``)
        self.wrist_ranges: dict[str, WristRange] = (
            {s: WristRange(self.robot, s, self.arms[s].centre) for s in self.arms}
            if self.config.wrist_range and self.config.elbow_placement == "swivel"
            else {}
        )
        #: the push of wrist targets out of the trunk (``trunk_clearance``; None: off, or the profile has no trunk)
        self.trunk: TrunkClearance | None = None
        if self.config.trunk_clearance:
            try:
                self.trunk = TrunkClearance(
                    self.robot,
                    {s: prof.frames[wrist_of(s)] for s in SIDES},
                    fast_clearance=self.config.trunk_clearance_fast,
                    hand_frames={s: prof.orientation_frame(wrist_of(s)) for s in SIDES},
                )
            except NoTrunkError as exc:  # the default asks for it on every robot; this one's profile cannot give it
                log.warning("trunk clearance off: %s", exc)
        #: side -> the low-passed speed of its mapped wrist target, which sets the push's clearance
        self._hand_speed = {s: HandSpeed() for s in SIDES}
        #: the operator's chest rotation -> the robot's waist angles (None: the profile has no waist the split fits)
        self.waist_map: WaistMap | None = _waist_map(prof)
        #: the operator's chest orientation (3, 3) at the calibration (pelvis frame), None until a frame gives one
        self._chest_rest: np.ndarray | None = None
        #: side -> rows of its wrist and elbow in the per-frame target arrays (``TARGET_NAMES`` order)
        self._arm_rows = {s: (TARGET_NAMES.index(wrist_of(s)), TARGET_NAMES.index(elbow_of(s))) for s in SIDES}
        #: side -> (swivel elbow, operator shoulder, operator elbow) placed for the current frame
        self._placed: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        #: side -> unit swivel direction of that placement (``elbow.swivel_direction``), the next frame's prior
        self._placed_dir: dict[str, np.ndarray] = {}
        self.rejects: Counter[str] = Counter()
        self.counts: Counter[str] = Counter()
        self.last_reject: tuple[str, str] | None = None
        self.calibration: Calibration | None = None
        self._recalibrate = calibration is None and self.config.auto_calibrate
        self._calib_tries = 0
        self._ignored: set[str] = set()  # sources named once as ignored
        #: frames received per source (the first MAX_SOURCES names), for "which sources are there?"
        self.sources_seen: Counter[str] = Counter()
        self._source: str | None = None  # the followed source (kept across stream resets)
        self._source_t0 = 0  # t0 [ns] of the followed source's last frame
        self._reset_stream()
        if calibration is not None:
            self.set_calibration(calibration)

    # ------------------------------------------------------------------ state

    def _reset_stream(self) -> None:
        """Forget frame history (velocities, last seq/stamp, held poses, incremental anchors)."""
        self._guard = SequenceGuard(resync_after=self.config.resync_after)
        n = len(TARGET_NAMES)
        # Per target, one row each, in TARGET_NAMES order (all four targets go through one array
        # operation per step, not ~25 small ones per target).
        #: last published valid position (n, 3) [m] and orientation (n, 3, 3); the robot rest pose before any
        self._held_p = np.array([self.robot_rest[t][0] for t in TARGET_NAMES])
        self._held_R = np.array([self.robot_rest[t][1] for t in TARGET_NAMES])
        #: whether the previous frame gave the target (velocities difference against _held_* then)
        self._has_prev = [False] * n
        self._eye_stack = np.tile(np.eye(3), (n, 1, 1))
        self._use_rotation = [t in WRISTS or self.config.elbow_rotation for t in TARGET_NAMES]
        #: side -> unit swivel direction of the previous frame's elbow placement (``ArmGeometry.place``'s prior)
        self._swivel_prior: dict[str, np.ndarray] = {}
        self._no_rotation = [False] * len(TARGET_NAMES)  # a source without measured orientations
        #: low-pass filtered linear [m/s] and angular [rad/s] velocities, a row per target
        self._vfilt = LowPassVelocity(self.config.velocity_tau, self.config.max_gap, rows=n)
        self._wfilt = LowPassVelocity(self.config.velocity_tau, self.config.max_gap, rows=n)
        for ua in getattr(self, "upper_arm_maps", {}).values():
            ua.reset()
        for arm in getattr(self, "consistent", {}).values():
            arm.reset()
        for wr in getattr(self, "wrist_ranges", {}).values():
            wr.reset()
        for hs in getattr(self, "_hand_speed", {}).values():
            hs.reset()
        #: side -> the exit ray of its wrist target's last trunk push (``TrunkClearance.push``), while it lasts
        self._trunk_ray: dict[str, np.ndarray] = {}
        for m in getattr(self, "_pos_map", {}).values():
            if isinstance(m, IncrementalMap):
                m.reanchor()

    def set_calibration(self, calibration: Calibration) -> None:
        """Install an operator calibration: rebuilds the per-target maps and restarts the stream state."""
        self.calibration = calibration
        self._recalibrate = False
        self._chest_rest = None  # the chest's rest: the first frame of this calibration that measures it
        ws = self.workspace
        self._pos_map: dict[str, AbsoluteMap | IncrementalMap] = {}
        self._rot_map: dict[str, OrientationMap] = {}
        for t in TARGET_NAMES:
            if self.config.mode == "incremental":
                self._pos_map[t] = IncrementalMap(
                    np.clip(self.robot_rest[t][0], ws.lower[t], ws.upper[t]),
                    self.config.incremental_scale,
                    ws.lower[t],
                    ws.upper[t],
                )
            else:
                # "reach" keeps the bounded box map as its fallback for frames without the arm's shoulder
                box_mode = "bounded" if self.config.mode == "reach" else self.config.mode
                self._pos_map[t] = AbsoluteMap.build(
                    box_mode, calibration.rest[t], calibration.lower[t], calibration.upper[t],
                    ws.lower[t], ws.upper[t],
                )  # fmt: skip
        maps = [self._pos_map[t] for t in TARGET_NAMES]
        #: the four absolute maps as one (4, 3) map (None in incremental mode: stateful per target)
        self._box_map: AbsoluteMap | None = None
        if all(isinstance(m, AbsoluteMap) for m in maps) and len({m.clamp for m in maps}) == 1:
            stack = {
                f: np.array([getattr(m, f) for m in maps]) for f in ("H_s", "U_s", "M_up", "M_down", "U_min", "U_max")
            }
            self._box_map = AbsoluteMap(**stack, clamp=maps[0].clamp)
        if self.config.orientation_reference == "rest":
            for t in TARGET_NAMES:
                self._rot_map[t] = OrientationMap(quat_to_matrix(calibration.rest_q[t]), self.robot_rest[t][1])
        # "posture": built on the next frame, which gives the operator's shoulders (_posture_maps).
        self._rest_reach: dict[str, np.ndarray] = {}
        self._reset_stream()
        log.info("calibration installed (%s), mode %s", calibration.source, self.config.mode)

    @property
    def followed_source(self) -> str | None:
        """The source whose frames are retargeted: the chosen one, else the one followed now (None: none yet)."""
        return self.config.source or self._source

    def follow_source(self, name: str) -> None:
        """Follow source ``name`` from now on, explicitly ("": back to the first one seen).

        Frames of every other source are then rejected as ``other_source``, each named once in
        the log again (the choice changed what is ignored).
        """
        self.config.source = name
        self._ignored.clear()
        if name:
            log.info("following source %r, chosen explicitly: frames of any other are rejected (other_source)", name)
        else:
            log.info("no source chosen: following the first one seen until it is silent")

    def _calibration_from(self, frame: HumanFrame) -> Calibration:
        """The operator's calibration from one rest frame: from the wrists alone for a wrist-only source."""
        if is_wrist_only(frame):
            return from_wrists(frame, self.bone_of, self.config.arm_length)
        return anthropometric(frame, self.bone_of)

    def rest_targets(self) -> dict[str, np.ndarray]:
        """Robot target for the operator at rest, target -> (3,) [m] (``U_ps`` of eq. 1; the current
        target in incremental mode); empty before any calibration."""
        if self.calibration is None:
            return {}
        out = {t: (m.U_s if isinstance(m, AbsoluteMap) else m.U).copy() for t, m in self._pos_map.items()}
        return out | {t: p.copy() for t, p in self._rest_reach.items()}

    # ------------------------------------------------------------------ step

    def _follows(self, frame: HumanFrame) -> bool:
        """Whether ``frame`` comes from the source this retargeter follows (see ``RetargetConfig.source``).

        Two sources on one key would otherwise make the robot jump between two operators every
        frame; the others are rejected (``other_source``) and each is named once.
        """
        want = self.config.source
        if want:
            ok = frame.source == want
        else:
            silent = (frame.hdr.t0 - self._source_t0) * 1e-9 > self.config.source_timeout
            ok = self._source is None or frame.source == self._source or silent
            if ok and self._source is not None and frame.source != self._source:
                log.info("source %r silent for over %.1f s", self._source, self.config.source_timeout)
        if not ok:
            if frame.source not in self._ignored:
                self._ignored.add(frame.source)
                log.warning(
                    "ignoring frames of source %r: following %r (choose with `mimic retarget --source NAME`)",
                    frame.source,
                    want or self._source,
                )
            self._reject("other_source", f"source {frame.source!r} while following {want or self._source!r}")
        return ok

    def _check_order(self, hdr: Header, source: str) -> bool:
        verdict = self._guard.check(hdr, source)
        if verdict.restarted:
            log.warning("%s; resynchronising", verdict.detail)
            self.counts["resync"] += 1
            self._reset_stream()
            self._source = source
        elif not verdict.ok:
            self._reject(verdict.reason, verdict.detail)
        return verdict.ok

    def step(self, frame: HumanFrame) -> TaskTargets | None:
        """Retarget one frame.

        Returns:
            TaskTargets with ``frame.hdr`` copied unchanged, or None when the frame is rejected
            (order) or no calibration is available yet; ``last_reject`` then says why.
        """
        self.last_reject = None
        hdr = frame.hdr
        if frame.source in self.sources_seen or len(self.sources_seen) < MAX_SOURCES:
            self.sources_seen[frame.source] += 1
        if not self._follows(frame):
            return None
        if self._source is not None and frame.source != self._source:
            # Another clip or device: its seq and clock start afresh, which is not disorder.
            log.info("following source %r (was %r): new stream", frame.source, self._source)
            self.counts["new_source"] += 1
            self._reset_stream()
        self._source = frame.source
        self._source_t0 = hdr.t0
        if not self._check_order(hdr, frame.source):
            return None
        last_stamp = self._guard.last_stamp(frame.source)
        dt = None if last_stamp is None else hdr.stamp - last_stamp
        self._guard.accept(hdr, frame.source)
        calibrated = self._calibrated(frame, hdr, self._calibration_from, CALIBRATION_HINT)
        if calibrated == "rejected":
            return None
        if calibrated == "new":
            dt = None
        if not self._rot_map:
            self._posture_maps(frame)
        self.counts["frames"] += 1
        self._placed.clear()
        self._placed_dir.clear()
        if dt is None or dt > self.config.max_gap:  # a new stream or a gap: the operator's arms may be anywhere
            self._swivel_prior.clear()
        targets = self._targets(frame, dt)
        upper_arms = {}
        for side, ua_map in self.upper_arm_maps.items():
            wrist = targets[f"{side}_wrist"]
            placed = self._place_elbow(side, frame, wrist.p) if wrist.valid else None
            if placed is not None:
                upper_arms[side] = matrix_to_quat(ua_map(placed[0], wrist.p))
        self._swivel_prior.update(self._placed_dir)  # the next frame's prior: this frame's last placements
        return TaskTargets(
            Header(hdr.seq, hdr.stamp, hdr.t0),
            targets,
            mode=self.config.mode,
            upper_arms=upper_arms,
            waist=self._waist(frame),
        )

    def _waist(self, frame: HumanFrame) -> np.ndarray:
        """(3,) [rad] the robot's waist angles for the operator's chest rotation since the calibration
        (:class:`.torso.WaistMap`, clipped into the ranges), empty without a measured chest orientation. The
        calibration frame (or, with a calibration from a file, the first frame after it that measures the chest)
        is the chest's rest."""
        R = chest_rotation(frame) if self.waist_map is not None else None
        if R is None:
            return np.zeros(0)
        if self._chest_rest is None:
            self._chest_rest = R
        raw = self.waist_map.angles(R, self._chest_rest)
        q = np.clip(raw, self.waist_map.lower, self.waist_map.upper)
        for j, clipped in zip(self.waist_map.joints, q != raw, strict=True):
            if clipped:
                self.counts[f"waist_clipped_{j}"] += 1
        return q

    def _posture_maps(self, frame: HumanFrame) -> None:
        """Eq. (4) offsets against the robot's calibration posture (``orientation_reference="posture"``).

        The posture reaches the calibration wrist targets ``U_ps`` with the wrist joints at zero and,
        with swivel elbows, the elbow target of the operator's calibration pose (their shoulder from
        this frame, their elbow and wrist from the calibration).
        """
        cal = self.calibration
        for side, rmap in self.reach.items():
            sh = frame.bones.get(f"{side}_shoulder")
            if sh is not None and sh.valid:
                u, rho = operator_reach(sh.p, cal.rest[f"{side}_elbow"], cal.rest[f"{side}_wrist"])
                self._rest_reach[f"{side}_wrist"] = self.arms[side].reachable(rmap.map(u, rho))
        rest = self.rest_targets()
        elbows = {}
        for side, arm in self.arms.items():
            sh = frame.bones.get(f"{side}_shoulder")
            if sh is not None and sh.valid and self.config.elbow_placement == "swivel":
                shoulder = np.asarray(sh.p, dtype=float)
                swivel = human_swivel(shoulder, cal.rest[elbow_of(side)], cal.rest[wrist_of(side)])
                elbows[side] = arm.place(rest[wrist_of(side)], swivel)
        ref = calibration_orientations(self.robot, rest, elbows)
        for t in TARGET_NAMES:
            side = side_of(t)
            if self.config.orientation_reference == "forearm" and t in WRISTS and side in elbows:
                sh = np.asarray(frame.bones[f"{side}_shoulder"].p, dtype=float)
                h_el = cal.rest[elbow_of(side)]
                A = arm_alignment(
                    h_el - sh,
                    cal.rest[t] - h_el,
                    elbows[side] - self.arms[side].centre,
                    rest[t] - elbows[side],
                    self.config.forearm_blend,
                )
                self._rot_map[t] = ForearmOrientationMap(quat_to_matrix(cal.rest_q[t]), ref[t], A)
            else:
                self._rot_map[t] = OrientationMap(quat_to_matrix(cal.rest_q[t]), ref[t])

    def _place_elbow(
        self, side: str, frame: HumanFrame, wrist_p: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Swivel elbow for this frame's wrist target ``wrist_p`` (3,) [m], not clamped, with the
        operator's shoulder and elbow (3,) [m] it came from; None when it cannot be placed (no swivel
        placement, incremental mode, or an invalid arm bone). Placed once per side and frame: the
        forearm orientation of the wrist and the elbow target share it."""
        placed = self._placed.get(side)
        if placed is not None:
            return placed
        arm = self.arms.get(side)
        if arm is None or self.config.mode == "incremental" or self.config.elbow_placement != "swivel":
            return None
        bones = [frame.bones.get(f"{side}_{b}") for b in ("shoulder", "elbow", "wrist")]
        if any(b is None or not b.valid for b in bones):
            return None
        h_sh, h_el, h_wr = (np.asarray(b.p, dtype=float) for b in bones)
        placed = (arm.place(wrist_p, human_swivel(h_sh, h_el, h_wr), self._swivel_prior.get(side)), h_sh, h_el)
        self._placed[side] = placed
        if (d := swivel_direction(arm.centre, placed[0], wrist_p)) is not None:
            self._placed_dir[side] = d
        return placed

    def _swivel_occluded(self, side: str, frame: HumanFrame) -> bool:
        """True when this arm's swivel elbow cannot be placed on this frame because the source lost its shoulder or
        wrist (a bone it gives, invalid here: an occluded marker). The elbow target is then held with the wrist's,
        as an invalid target, instead of switching to the box map for those frames: on the Vicon box lift the wrist
        markers drop out for 29 frames and the elbow target jumped 7.5 cm between the two placements, back and forth
        (HQP elbow p99 7.8 cm). A source that never gives those bones keeps the box map."""
        if side not in self.arms or self.config.mode == "incremental" or self.config.elbow_placement != "swivel":
            return False
        return any(
            (b := frame.bones.get(f"{side}_{name}")) is not None and not b.valid for name in ("shoulder", "wrist")
        )

    def _elbow_in_box(self, t: str, p: np.ndarray) -> np.ndarray:
        """A swivel elbow target (3,) [m] as published: kept in the workspace box in bounded mode."""
        if self.config.mode != "bounded":
            return p  # "reach": the box is not the reachable set; the swivel pair is
        # Still kept in the box (one elbow in five on the real clips, up to 1.7 cm off the
        # forearm length): without it `mimic eval` tracked slightly worse (elbow 0.94 -> 0.96 cm,
        # wrist 0.068 -> 0.078 cm mean, hqp-nullspace on the 16 clips); the box's outer 5 %
        # are near the joint stops.
        ws = self.workspace
        q = np.clip(p, ws.lower[t], ws.upper[t])
        if np.any(np.abs(q - p) > 1e-9):
            self.counts[f"clamped_{t}"] += 1
        return q

    def _reach_target(self, t: str, side: str, frame: HumanFrame) -> np.ndarray | None:
        """ "reach" mode position (3,) [m] of a wrist (or, with mapped elbows, an elbow): the operator's
        direction from their shoulder and reach ratio onto the robot's reach map; None without the
        arm's bones (the caller falls back to the box map)."""
        bones = [frame.bones.get(f"{side}_{b}") for b in ("shoulder", "elbow", "wrist")]
        if any(b is None or not b.valid for b in bones):
            return None
        h_sh, h_el, h_wr = (np.asarray(b.p, dtype=float) for b in bones)
        arm = self.arms[side]
        if t.endswith("elbow"):  # mapped elbows: the operator's upper-arm direction at the robot's length
            d = h_el - h_sh
            n = float(np.linalg.norm(d))
            return arm.centre + arm.upper * (d / n if n > 1e-9 else arm.default_swivel)
        u, rho = operator_reach(h_sh, h_el, h_wr)
        p = self.reach[side].map(u, rho)
        q = arm.reachable(p)
        if np.any(np.abs(q - p) > 1e-9):
            self.counts[f"reach_clamped_{t}"] += 1
        return q

    def _position(self, t: str, frame: HumanFrame, H: np.ndarray, mapped, done: dict[str, np.ndarray]) -> np.ndarray:
        """Position (3,) [m] of valid target ``t`` whose bone is at ``H`` (3,) [m]; ``mapped`` is its box map's
        ``(U, clamped)`` when computed with the others (None: map it here); ``done``: the wrists placed so far."""
        side = side_of(t)
        p = None
        if t in ELBOWS:
            wrist_p = done.get(wrist_of(side))
            placed = self._place_elbow(side, frame, wrist_p) if wrist_p is not None else None
            if placed is not None:
                p = self._elbow_in_box(t, placed[0])
        if p is None and side in self.reach:
            p = self._reach_target(t, side, frame)
        if p is None:
            p, clamped = mapped if mapped is not None else self._pos_map[t](H)
            if clamped.any():
                self.counts[f"clamped_{t}"] += 1
            if side in self.reach and t.endswith("wrist"):
                p = self.reach[side].project(p)
            arm = self.arms.get(side)
            if t in WRISTS and arm is not None and self.config.mode != "incremental":
                # Swivel elbows: keep the wrist within the arm's reach so the pair stays reachable.
                q = arm.reachable(p)
                if np.any(np.abs(q - p) > 1e-9):
                    self.counts[f"reach_clamped_{t}"] += 1
                p = q
        return p

    def _make_consistent(self, P: np.ndarray, R: np.ndarray, valid: list[bool], dt: float | None) -> None:
        """Per arm with a valid wrist and elbow: the elbow row of ``P`` (4, 3) [m] and the wrist row of
        ``R`` (4, 3, 3) (and the elbow's, with ``elbow_rotation``) become the targets of the arm
        posture closest to them (:class:`.consistent.ConsistentArm`), in place. Warm-started from the
        previous frame's posture; from rest after a gap (``max_gap``) or a new stream."""
        gap = dt is None or dt > self.config.max_gap
        for side, arm in self.consistent.items():
            iw, ie = self._arm_rows[side]
            if not (valid[iw] and valid[ie]):
                continue  # wrist-only (or invalid) arms are published as mapped
            if gap:
                arm.reset()
            recoveries = arm.recoveries
            P[ie], R[iw], elbow_R = arm(P[iw], P[ie], R[iw])
            if arm.recoveries != recoveries:  # the warm posture was stuck (status: how often)
                self.counts[f"consistent_recovered_{side}"] += 1
            if self._use_rotation[ie]:
                R[ie] = elbow_R

    def _clear_trunk(
        self,
        frame: HumanFrame,
        P: np.ndarray,
        R: np.ndarray,
        H: np.ndarray,
        valid: list[bool],
        mapped,
        dt: float | None,
    ) -> None:
        """Per arm with a valid wrist: the wrist row of ``P`` (4, 3) [m] pushed out of the trunk with its hand at
        ``R``'s wrist row (:class:`.trunk.TrunkClearance`), in place, and the elbow row placed again for it (the
        swivel elbow hangs at the forearm length from the wrist). The wrist orientation stays as mapped; the
        clearance follows the mapped wrist's low-passed speed (``trunk_clearance_fast``); dt [s] since the previous
        frame (None or past ``max_gap``: the speed restarts)."""
        gap = dt is None or dt > self.config.max_gap
        for side in SIDES:
            iw, ie = self._arm_rows[side]
            prior = None if gap else self._trunk_ray.get(side)  # after a gap it belongs to another motion
            self._trunk_ray.pop(side, None)
            if not valid[iw]:
                self._hand_speed[side].reset()
                continue
            speed = self._hand_speed[side].update(P[iw], None if gap else dt)
            wrist = P[iw]  # one view: ``P[iw]`` makes a new one each time, never the object push() returns
            p, ray = self.trunk.push(side, wrist, R[iw], speed, prior, wrist - P[ie] if valid[ie] else None)
            if ray is not None:
                self._trunk_ray[side] = ray
            if p is wrist:
                continue
            P[iw] = p
            self.counts[f"trunk_cleared_{side}"] += 1
            if not valid[ie]:
                continue
            box = None if mapped is None else (mapped[0][ie], mapped[1][ie])
            for _ in range(TRUNK_PASSES - 1):
                self._place_again(side, frame, P, H, box)
                # the elbow placed for the pushed wrist turns the forearm, and the hand on it: clear it again
                wrist = P[iw]
                again, _ = self.trunk.push(side, wrist, R[iw], speed, ray, wrist - P[ie])
                if again is wrist:
                    break
                P[iw] = again
            else:  # the last push moved the wrist: its elbow follows
                self._place_again(side, frame, P, H, box)

    def _place_again(self, side: str, frame: HumanFrame, P: np.ndarray, H: np.ndarray, box) -> None:
        """The elbow row of ``P`` (4, 3) [m] placed again for the wrist row as it now is (the swivel elbow hangs at the
        forearm length from the wrist), in place; ``box``: the elbow's box-map bounds (None: none)."""
        iw, ie = self._arm_rows[side]
        self._placed.pop(side, None)
        P[ie] = self._position(TARGET_NAMES[ie], frame, H[ie], box, {wrist_of(side): P[iw]})

    def _targets(self, frame: HumanFrame, dt: float | None) -> dict[str, Target]:
        """All targets of one frame (wrists first: the swivel elbows need them).

        Positions go target by target (each mode places them its own way); the rest runs on all
        four at once: the bone orientations, eq. (4), the velocity differences and their
        low-pass, the quaternions. Same arithmetic as one target at a time (the bones are not
        checked again: the frame's decoder did).
        """
        n = len(TARGET_NAMES)
        bones: list[Bone | None] = [frame.bones.get(self.bone_of[t]) for t in TARGET_NAMES]
        valid = [b is not None and b.valid and not (t in ELBOWS and self._swivel_occluded(side_of(t), frame))
                 for t, b in zip(TARGET_NAMES, bones, strict=True)]  # fmt: skip
        all_valid = all(valid)
        H = np.zeros((n, 3))
        Q = np.zeros((n, 4))
        for i, b in enumerate(bones):
            if valid[i]:
                H[i] = b.p
                Q[i] = b.q
            else:
                Q[i, 0] = 1.0
        mapped = self._box_map(H) if self._box_map is not None else None
        P = self._held_p.copy()  # invalid targets hold their last valid pose
        left = self._eye_stack.copy()  # eq. (4) as left @ R_H @ right per target
        right = self._eye_stack.copy()
        done: dict[str, np.ndarray] = {}
        for i, t in enumerate(TARGET_NAMES):
            if not valid[i]:
                self.counts[f"invalid_{t}"] += 1
                pos_map = self._pos_map[t]
                if isinstance(pos_map, IncrementalMap):
                    pos_map.reanchor()
                continue
            P[i] = self._position(t, frame, H[i], None if mapped is None else (mapped[0][i], mapped[1][i]), done)
            if t in WRISTS:
                done[t] = P[i]
            rot_map = self._rot_map[t]
            right[i] = rot_map.R_HU
            if isinstance(rot_map, ForearmOrientationMap):
                side = side_of(t)
                placed = self._place_elbow(side, frame, P[i])
                if placed is not None:
                    elbow, h_sh, h_el = placed
                    c = self.arms[side].centre
                    left[i] = arm_alignment(
                        h_el - h_sh, H[i] - h_el, elbow - c, P[i] - elbow, self.config.forearm_blend
                    )
                    right[i] = rot_map.right
        R = left @ quats_to_matrices(Q) @ right
        if not all_valid:
            for i in range(n):
                if not valid[i]:
                    R[i] = self._held_R[i]
        if self.trunk is not None:
            self._clear_trunk(frame, P, R, H, valid, mapped, dt)
        for side, wr in self.wrist_ranges.items():
            iw, ie = self._arm_rows[side]
            if valid[iw] and valid[ie]:  # (the forearm needs both; wrist-only arms are published as mapped)
                R_in = R[iw]
                out = wr(R_in, P[ie], P[iw])
                if out is not R_in:  # (returned as given when within the ranges)
                    R[iw] = out
                    self.counts[f"wrist_range_{side}"] += 1
        if self.consistent:
            self._make_consistent(P, R, valid, dt)
        # Velocities: finite differences with the previous frame, low-passed; a target without a previous
        # sample restarts from zero.
        fresh = [v and h for v, h in zip(valid, self._has_prev, strict=True)]
        raw_v = raw_w = None
        if dt is not None and dt > 0 and any(fresh):
            rows = slice(None) if all(fresh) else np.flatnonzero(fresh)
            raw_v = (P[rows] - self._held_p[rows]) / dt
            raw_w = np.array([angular_velocity(R0, R1, dt) for R0, R1 in zip(self._held_R[rows], R[rows], strict=True)])
        V = self._vfilt.update_rows(raw_v, dt, fresh)
        W = self._wfilt.update_rows(raw_w, dt, fresh)
        self._has_prev = valid
        self._held_p = P
        self._held_R = R
        q = matrices_to_quats(R)
        # A source without measured orientations (markers only: identity placeholders) gives no hand orientation
        # to copy: mapped as real, the hand would stay fixed in the pelvis frame while the forearm moves and the
        # solver would twist the wrist to its stops chasing it (h12r: the Vicon clip, 356 of 521 frames past
        # the wrist's ranges). Its targets carry no rotation; the solver then tracks positions only.
        use = self._use_rotation if frame.oriented else self._no_rotation
        return {
            t: Target(P[i], q[i], V[i], W[i], valid=valid[i], use_rotation=use[i]) for i, t in enumerate(TARGET_NAMES)
        }
