"""Retargeting for a mobile robot (a wheeled-legged arm, seed 002): the operator's hand drives the gripper.

The G1's :class:`~services.retarget.retargeter.Retargeter` maps both arms into a fixed base
frame through a sampled reach set. A robot whose torso rolls has no such set: its hand can go
wherever the base can drive. So this retargeter does what the profile's ``[retarget]`` table
says (see ``models/tita_piper.toml``):

* one target (``target``, e.g. ``right_wrist``) from one operator bone (``bone``);
* its frame is the world frame Σw the robot started in (the planner plans in it);
* calibration as for the G1 (:func:`~services.retarget.calibration.anthropometric`: the first
  frame with the arms hanging, or ``mimic calibrate``) gives the bone's rest point ``h_rest``
  in the operator's pelvis frame;
* ``p = p_start + scale * (h - h_rest)`` with ``p_start`` the gripper at the profile's start
  pose (forward kinematics of the planner's model), clipped to the box ``[lower, upper]`` in Σw;
* velocity: the finite difference of consecutive targets, low-passed
  (:class:`~services.retarget.velocity.LowPassVelocity`, ``RetargetConfig.velocity_tau``).

Frame order, sources and calibration behave as in the G1 retargeter: non-increasing frames
are rejected (:class:`~shared.sequence.SequenceGuard`), frames of a second source while one is
followed are rejected as ``other_source``, an invalid bone publishes the last target held
(``valid=False``). Orientation is not used by the planner: the target carries the identity
with ``use_rotation=False``.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass

import numpy as np

from services.retarget.calibration import Calibration, CalibrationError, anthropometric
from services.retarget.intake import FrameIntake
from services.retarget.velocity import LowPassVelocity
from shared.messages import Header, HumanFrame, Target, TaskTargets
from shared.robot.profile import ProfileError
from shared.robot.wheeled import WheeledRobot, build_wheeled_robot
from shared.sequence import SequenceGuard
from shared.targets import TARGET_NAMES

log = logging.getLogger(__name__)

_IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True)
class MobileMap:
    """The profile's ``[retarget]`` table, checked.

    Attributes:
        target: TaskTargets name published (one of ``TARGET_NAMES``). bone: operator bone driving it.
        scale: (3,) operator displacement -> hand displacement per axis [-].
        lower, upper: (3,) workspace box in Σw [m]. start: (3,) hand at the start pose in Σw [m].
    """

    target: str
    bone: str
    scale: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    start: np.ndarray

    @classmethod
    def from_robot(cls, robot: WheeledRobot) -> MobileMap:
        """Read and check ``[retarget]`` of the robot's profile.

        Raises:
            ProfileError: the table is missing, a field is missing or malformed, or the start hand
                lies outside the box.
        """
        prof = robot.profile
        t = prof.retarget
        where = f"{prof.source} [retarget]"
        if not t:
            raise ProfileError(f"{prof.source}: no [retarget] table: this robot cannot be retargeted onto")
        try:
            target, bone = str(t["target"]), str(t["bone"])
            vec = {k: np.asarray(t[k], dtype=float) for k in ("scale", "lower", "upper")}
        except KeyError as exc:
            raise ProfileError(f"{where}: missing field {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ProfileError(f"{where}: {exc}") from None
        if target not in TARGET_NAMES:
            raise ProfileError(f"{where}: target {target!r} is not one of {list(TARGET_NAMES)}")
        for k, v in vec.items():
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ProfileError(f"{where}: {k} must be 3 finite numbers, got {t[k]!r}")
        if np.any(vec["scale"] < 0) or not np.any(vec["scale"] > 0) or np.any(vec["lower"] >= vec["upper"]):
            raise ProfileError(f"{where}: scale must be >= 0 (not all 0) and lower < upper on every axis")
        q0 = np.r_[prof.start_base, prof.start_arm]
        start = robot.kin.evaluate(q0, np.zeros_like(q0))[0]
        if np.any(start < vec["lower"]) or np.any(start > vec["upper"]):
            raise ProfileError(f"{where}: the start hand {np.round(start, 3).tolist()} m lies outside the box")
        return cls(target, bone, vec["scale"], vec["lower"], vec["upper"], np.asarray(start, dtype=float))

    def __call__(self, h: np.ndarray, h_rest: np.ndarray) -> tuple[np.ndarray, bool]:
        """Hand target (3,) in Σw [m] for the operator bone at ``h`` (3,) [m, pelvis frame]; clipped?"""
        p = self.start + self.scale * (np.asarray(h, dtype=float) - h_rest)
        q = np.clip(p, self.lower, self.upper)
        return q, bool(np.any(q != p))


class MobileWorkspace:
    """The box as the retarget config queryable reports it (same shape as the G1's ``Workspace.summary``)."""

    def __init__(self, m: MobileMap):
        self.map = m

    def summary(self) -> dict:
        m = self.map
        return {
            m.target: {"lower": np.round(m.lower, 4).tolist(), "upper": np.round(m.upper, 4).tolist()},
            "frame": "world frame the robot started in",
            "start": np.round(m.start, 4).tolist(),
            "scale": m.scale.tolist(),
        }


class MobileRetargeter(FrameIntake):
    """HumanFrames (operator pelvis frame) -> one hand target in the robot's start frame Σw.

    The same interface as :class:`~services.retarget.retargeter.Retargeter` (what
    :class:`~services.retarget.node.RetargetNode` calls). Of the RetargetConfig it uses
    ``robot``, ``velocity_tau``, ``max_gap``, ``resync_after``, ``auto_calibrate``,
    ``one_arm_after`` and ``source``; the mapping and workspace fields are the G1's (ignored here:
    the profile's ``[retarget]`` table holds this robot's).

    Args:
        config: RetargetConfig (``robot`` = a wheeled profile).
        calibration: operator calibration; None = auto-calibrate on the first rest frame.
        robot: the wheeled robot (None: built from ``config.robot``).
    """

    def __init__(self, config, calibration: Calibration | None = None, robot: WheeledRobot | None = None):
        self.config = config
        self.robot = robot or build_wheeled_robot(config.robot)
        self.map = MobileMap.from_robot(self.robot)
        self.workspace = MobileWorkspace(self.map)
        self.rejects: Counter[str] = Counter()
        self.counts: Counter[str] = Counter()
        self.last_reject: tuple[str, str] | None = None
        self.calibration: Calibration | None = None
        self._recalibrate = calibration is None and config.auto_calibrate
        self._calib_tries = 0
        self._source: str | None = None
        self._reset_stream()
        if calibration is not None:
            self.set_calibration(calibration)

    def _reset_stream(self) -> None:
        self._guard = SequenceGuard(resync_after=self.config.resync_after)
        self._prev: np.ndarray | None = None
        self._held = self.map.start.copy()
        self._vfilt = LowPassVelocity(self.config.velocity_tau, self.config.max_gap)

    def set_calibration(self, calibration: Calibration) -> None:
        """Install an operator calibration (its rest point of the driving target); restarts the stream."""
        if self.map.target not in calibration.rest:
            raise CalibrationError(f"calibration has no rest point for {self.map.target}")
        self.calibration = calibration
        self._recalibrate = False
        self._reset_stream()
        log.info("calibration installed (%s): %s rest %s", calibration.source, self.map.target,
                 np.round(calibration.rest[self.map.target], 3).tolist())  # fmt: skip

    def step(self, frame: HumanFrame) -> TaskTargets | None:
        """Retarget one frame: TaskTargets with the one hand target, or None (``last_reject`` says why)."""
        self.last_reject = None
        hdr = frame.hdr
        want = self.config.source
        if (want and frame.source != want) or (not want and self._source not in (None, frame.source)):
            self._reject("other_source", f"source {frame.source!r} while following {want or self._source!r}")
            return None
        if self._source is None:
            self._source = frame.source
        verdict = self._guard.check(hdr, frame.source)
        if verdict.restarted:
            log.warning("%s; resynchronising", verdict.detail)
            self.counts["resync"] += 1
            self._reset_stream()
        elif not verdict.ok:
            self._reject(verdict.reason, verdict.detail)
            return None
        last = self._guard.last_stamp(frame.source)
        dt = None if last is None else hdr.stamp - last
        self._guard.accept(hdr, frame.source)
        bones = {t: t for t in TARGET_NAMES} | {self.map.target: self.map.bone}
        calibrated = self._calibrated(
            frame, hdr, lambda f: anthropometric(f, bones), "the operator must start at rest, arms hanging"
        )
        if calibrated == "rejected":
            return None
        if calibrated == "new":
            dt = None
        self.counts["frames"] += 1
        name = self.map.target
        bone = frame.bones.get(self.map.bone)
        if bone is None or not bone.valid:
            self.counts[f"invalid_{name}"] += 1
            self._prev = None
            self._vfilt.reset()
            target = Target(self._held.copy(), _IDENTITY_Q.copy(), np.zeros(3), np.zeros(3), valid=False)
        else:
            p, clipped = self.map(bone.p, self.calibration.rest[name])
            if clipped:
                self.counts[f"clamped_{name}"] += 1
            if self._prev is None or dt is None or dt <= 0:
                v = self._vfilt.update(None, 1.0)
            else:
                v = self._vfilt.update((p - self._prev) / dt, dt)
            self._prev = self._held = p
            target = Target(p, _IDENTITY_Q.copy(), v, np.zeros(3), valid=True, use_rotation=False)
        return TaskTargets(Header(hdr.seq, hdr.stamp, hdr.t0), {name: target}, mode="mobile")
