"""Pure simulation core: MuJoCo robot, servo targets, watchdog. No bus, no clock.

The robot comes from :func:`shared.robot.mujoco_model.build_mujoco_robot` (same URDF
as Pinocchio, pelvis welded to the world, every joint on a position servo, legs held
at rest). On top of the plain position servos the core adds what a real joint
controller does, all through the actuators so the URDF effort limits still bound
every torque:

* **velocity feedforward**: a MuJoCo position actuator with damping ``kv`` produces
  ``kp (ctrl - q) - kv qdot``. Shifting the target by ``kv/kp * qd_ref`` turns that
  into ``kp (q_ref - q) + kv (qd_ref - qdot)``, i.e. the servo damps the *tracking*
  velocity error instead of braking the motion (that brake alone costs ~9 degrees of
  lag on a 1 Hz, 30 degree sine);
* **gravity compensation**: ``body_gravcomp = 1`` routed through the actuators
  (``jnt_actgravcomp``), so gravity stays on in the physics and the motors hold it;
* **first-order hold**: between two commands the reference moves on with the commanded
  velocity (up to ``max_extrapolation``, then it brakes to a stop at ``a_max``), instead of
  a staircase at the command rate;
* **velocity and acceleration limits**: the servo target ``q_servo`` is not the reference
  itself but follows it as a joint would: ``|qd_servo| <= vmax``, ``|qdd_servo| <= a_max``
  (the robot model's per-joint ``amax``: the profile's ``max_joint_acceleration``, or each motor's
  ``[acceleration_limits]`` entry when ``motor_acceleration_limits`` is on), braking before the position limits and
  before the reference (:class:`~services.solver.bounds.JointBounds`, the solver's own
  bounds), so a watchdog resume, the very first command or a jump in the commands ramp
  up and settle instead of stepping the servo at full speed. The velocity feedforward
  is ``qd_servo``, the target's own velocity;
* **velocity-capped servo**: the actuator force ``kp (ctrl - q) - kv qdot`` equals
  ``kv (u - qdot)``: the servo drives the joint towards the velocity ``u``. ``u`` is capped
  at vmax, so a joint that lags its target catches up at vmax, not past it.

What the servo cannot hold: joints pushed past vmax by the other joints' motion (coupling)
or left behind by their effort limits (the wrist pitch/yaw motors give 5 Nm), see the README.

Time is simulated time ``data.time`` [s]; the watchdog runs on it too, so the core is
deterministic: the same commands at the same simulated times give identical states.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from services.solver.bounds import JointBounds
from shared.messages import Header, JointCommand, Pose, RobotState
from shared.robot.mujoco_model import MujocoRobot, build_mujoco_robot
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import DEFAULT_PROFILE, RobotProfile, load_profile
from shared.rotations import matrix_to_quat
from shared.targets import TARGET_NAMES

log = logging.getLogger("mimic.sim")

#: Tolerance on the URDF limits before a commanded q counts as "beyond limits" [rad].
LIMIT_TOL = 1e-6
#: Fraction of a_max the servo target may use to close a gap to the reference (the braking bound
#: towards it): the reference itself may accelerate with the rest (the solver plans with half).
CLOSING_DECEL = 0.5


@dataclass
class SimConfig:
    """Servo and watchdog settings of :class:`SimCore`.

    Attributes:
        timestep: physics step [s] (1 kHz default).
        watchdog: time without commands after which the last pose is held [s].
        velocity_feedforward: feed the commanded qd into the servo damping.
        gravity_compensation: motors cancel gravity (through the actuators).
        max_extrapolation: longest first-order hold past a command [s]; then the reference
            brakes to a stop at ``max_acceleration``.
        max_acceleration: acceleration cap of the servo target [rad/s^2] (None: the robot
            model's per-joint ``amax``, the limits the solver's commands keep).
        velocity_capped_servo: the velocity the servo drives a joint towards is capped at vmax
            (a drive's position loop saturating at its speed limit): a lagging joint catches up at
            vmax instead of past it.
        contacts: simulate contacts (self-collisions of the robot).
        contact_exclude_hops: no contacts between a body and its ancestors this many links
            up (the shoulder collision meshes overlap the torso: spurious contacts).
        solver_id: solver whose commands are followed (reported in RobotState).
    """

    timestep: float = 0.001
    watchdog: float = 0.1
    velocity_feedforward: bool = True
    gravity_compensation: bool = True
    max_extrapolation: float = 0.05
    max_acceleration: float | None = None
    velocity_capped_servo: bool = True
    contacts: bool = True
    contact_exclude_hops: int = 3
    solver_id: str = "main"

    def __post_init__(self) -> None:
        for name in ("timestep", "watchdog"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 s, got {getattr(self, name)}")
        if self.max_extrapolation < 0 or self.contact_exclude_hops < 0:
            raise ValueError(
                f"max_extrapolation ({self.max_extrapolation} s) and contact_exclude_hops "
                f"({self.contact_exclude_hops}) must be >= 0"
            )
        if self.max_acceleration is not None and not (0 < self.max_acceleration < math.inf):
            raise ValueError(f"max_acceleration must be > 0 rad/s^2 and finite, got {self.max_acceleration}")


#: |qd| / vmax above which a simulated joint counts as past its velocity limit (1 % for noise).
VELOCITY_TOLERANCE = 1.01


@dataclass
class SimCounters:
    """What happened to the commands given to :meth:`SimCore.apply`."""

    applied: int = 0
    clipped: int = 0
    rejects: dict[str, int] = field(default_factory=dict)
    last_reject: str = ""
    holds: int = 0
    #: physics steps in which a simulated joint moved faster than its velocity limit (the servo
    #: target is rate-limited, but a stiff servo catching up, contacts or gravity can overshoot)
    velocity_excess_steps: int = 0
    #: largest |qd| / vmax seen (> 1: past the limit) and the joint it was on
    worst_velocity_ratio: float = 0.0
    worst_velocity_joint: str = ""


class CommandError(ValueError):
    """A JointCommand the core refuses; ``reason`` is a short tag for status counters."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


class FollowerCore:
    """What every sim core shares with the sim service: hold state, counters, clock.

    A subclass builds ``self.robot`` (``.model``, ``.data``: MuJoCo), calls
    :meth:`_start_following` and implements ``check``, ``step_physics``, ``state`` and ``info``.
    """

    robot: Any
    counters: SimCounters

    def _start_following(self, solver_id: str) -> None:
        """Hold the start pose until the first command; nothing applied or rejected yet."""
        self._last_cmd_time: float | None = None
        self.holding = True  # holding the start pose until the first command
        self.hdr = Header(0, 0.0, 0)
        self.solver_id = solver_id
        self.counters = SimCounters()
        self._ncon_max = 0

    def _reject(self, exc: CommandError) -> bool:
        """Count a refused command by reason; always False (for :meth:`apply`)."""
        c = self.counters
        c.rejects[exc.reason] = c.rejects.get(exc.reason, 0) + 1
        c.last_reject = str(exc)
        return False

    def _accepted(self, cmd: JointCommand, now: float) -> None:
        """Bookkeeping of a command applied at ``now`` [s]: holding ends, its header is reported."""
        self._last_cmd_time = now
        self.holding = False
        self.hdr = cmd.hdr
        self.counters.applied += 1

    @property
    def dt(self) -> float:
        """Physics step [s]."""
        return float(self.robot.model.opt.timestep)

    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return float(self.robot.data.time)

    @property
    def max_contacts(self) -> int:
        """Largest number of simultaneous contacts seen so far."""
        return self._ncon_max


class SimCore(FollowerCore):
    """MuJoCo robot following JointCommands.

    Args:
        profile: robot profile (object, name or path; default ``DEFAULT_PROFILE``).
        config: servo and watchdog settings.
    """

    def __init__(self, profile: RobotProfile | str | None = None, config: SimConfig | None = None):
        self.config = cfg = config or SimConfig()
        prof = profile if isinstance(profile, RobotProfile) else load_profile(profile or DEFAULT_PROFILE)
        self.robot: MujocoRobot = build_mujoco_robot(
            prof,
            timestep=cfg.timestep,
            gravity_compensation=cfg.gravity_compensation,
            contact_exclude_hops=cfg.contact_exclude_hops,
        )
        kin = build_robot_model(prof, with_waist=True)
        self.joint_names: tuple[str, ...] = self.robot.joint_names
        order = [kin.joint_names.index(n) for n in self.joint_names]
        self._index = {n: i for i, n in enumerate(self.joint_names)}
        # Soft limits (profile margin applied) are where q is clipped; hard (URDF) limits
        # are where a command is refused outright.
        self.lower = kin.lower[order].copy()
        self.upper = kin.upper[order].copy()
        self.hard_lower = self.lower - prof.limit_margin
        self.hard_upper = self.upper + prof.limit_margin
        self.vmax = kin.vmax[order].copy()
        amax = kin.amax[order] if cfg.max_acceleration is None else np.full(len(order), cfg.max_acceleration)
        self.amax = np.array(amax, dtype=float)  # servo target acceleration limits (n,) [rad/s^2]
        # The servo target's motion box per physics step: vmax, a_max, braking before the soft limits.
        self._servo_bounds = JointBounds(self.lower, self.upper, self.vmax, self.amax)

        m = self.robot.model
        m.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST  # stiff servos need implicit damping
        if not cfg.contacts:
            m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        act = self.robot.act_idx
        # The velocity feedforward shifts ctrl past q_ref near a limit; the servo target
        # itself (q_servo) is always clipped into the soft limits below.
        m.actuator_ctrllimited[act] = 0
        self.kp = m.actuator_gainprm[act, 0].copy()
        self.kv = -m.actuator_biasprm[act, 2].copy()
        self._ff_gain = np.divide(self.kv, self.kp, out=np.zeros_like(self.kp), where=self.kp > 0)

        d = self.robot.data
        q0 = np.clip(d.qpos[self.robot.qpos_idx].copy(), self.lower, self.upper)
        self.robot.set_q(q0)
        mujoco.mj_forward(m, d)
        self.q_servo = q0.copy()  # velocity- and acceleration-limited servo target (n,) [rad]
        self.qd_servo = np.zeros_like(q0)  # its velocity (n,) [rad/s], the feedforward
        self._ref_q = q0.copy()  # last commanded q (clipped) (n,) [rad]
        self._ref_qd = np.zeros_like(q0)  # last commanded qd (n,) [rad/s]
        self._ref_t = 0.0  # sim time the last command was applied [s]
        self._hold_q = q0.copy()
        self._start_following(cfg.solver_id)

    def resume(self, q: np.ndarray) -> None:
        """Start from joint positions ``q`` (n,) [rad] (clipped into the limits), holding them, at rest.

        For a restarted sim: the robot continues from its last state instead of jumping to the
        profile rest pose.
        """
        q = np.clip(np.asarray(q, dtype=float), self.lower, self.upper)
        self.robot.set_q(q)
        self.robot.data.qvel[self.robot.dof_idx] = 0.0
        mujoco.mj_forward(self.robot.model, self.robot.data)
        self.q_servo, self._ref_q, self._hold_q = q.copy(), q.copy(), q.copy()
        self.qd_servo[:] = 0.0
        self._ref_qd[:] = 0.0
        self.holding = True

    # ------------------------------------------------------------------ properties

    @property
    def q(self) -> np.ndarray:
        """(n,) controlled joint positions [rad]."""
        return self.robot.data.qpos[self.robot.qpos_idx].copy()

    # ------------------------------------------------------------------ commands

    def check(self, cmd: JointCommand) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Validate a command against this robot.

        Returns:
            (idx (k,) joint indices, q (k,) [rad], qd (k,) [rad/s]).

        Raises:
            CommandError: unknown/duplicate/empty joint names ("joint_names"),
                length mismatch ("shape"), NaN/inf ("nan"), q beyond the URDF limits ("limits").
        """
        names = list(cmd.joints)
        if not names:
            raise CommandError("joint_names", "command names no joint")
        unknown = [n for n in names if n not in self._index]
        if unknown:
            raise CommandError("joint_names", f"unknown joints {unknown}; controlled: {list(self.joint_names)}")
        if len(set(names)) != len(names):
            raise CommandError("joint_names", "duplicated joint names")
        q = np.asarray(cmd.q, dtype=float).ravel()
        qd = np.asarray(cmd.qd, dtype=float).ravel()
        if q.shape != (len(names),) or qd.shape != (len(names),):
            raise CommandError("shape", f"{len(names)} joints but q {q.shape}, qd {qd.shape}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise CommandError("nan", "q or qd contains NaN or inf")
        idx = np.array([self._index[n] for n in names])
        lo, hi = self.hard_lower[idx] - LIMIT_TOL, self.hard_upper[idx] + LIMIT_TOL
        bad = np.flatnonzero((q < lo) | (q > hi))
        if bad.size:
            j = int(bad[0])
            raise CommandError(
                "limits", f"{names[j]} = {q[j]:.4f} rad outside [{lo[j] + LIMIT_TOL:.4f}, {hi[j] - LIMIT_TOL:.4f}]"
            )
        return idx, q, qd

    def apply(self, cmd: JointCommand, now: float | None = None) -> bool:
        """Take a command as the new servo reference.

        Args:
            cmd: the command; joints may be any subset of the controlled joints
                (the others keep their reference).
            now: time it is applied on the core's clock [s] (default: simulated time).

        Returns:
            True if applied; False if rejected (counted in :attr:`counters`, never applied).
        """
        try:
            idx, q, qd = self.check(cmd)
        except CommandError as exc:
            return self._reject(exc)
        now = self.time if now is None else float(now)
        qc = np.clip(q, self.lower[idx], self.upper[idx])  # last safety net: never past the soft limits
        if np.any(qc != q):
            self.counters.clipped += 1
        self._ref_q[idx] = qc
        self._ref_qd[:] = 0.0
        self._ref_qd[idx] = np.clip(qd, -self.vmax[idx], self.vmax[idx])
        self._ref_t = now
        if self.holding:
            # Info: a hold and its end are events an operator wants in the log (a few per run).
            log.info("commands resumed at t=%.3f s (seq %d)", now, cmd.hdr.seq)
        self._accepted(cmd, now)
        return True

    # ------------------------------------------------------------------ physics

    def _reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Where the servo target should be at time ``t`` [s]: (q (n,) [rad], qd (n,) [rad/s]).

        Holding: the held pose, at rest. Otherwise the last command held to first order for up
        to ``max_extrapolation``, then braking to a stop at a_max (no dead stop from full speed);
        clipped into the soft limits, at rest where clipped.
        """
        if self.holding:
            return self._hold_q, np.zeros_like(self._hold_q)
        cap = self.config.max_extrapolation
        h = max(t - self._ref_t, 0.0)
        qd = self._ref_qd
        q = self._ref_q + qd * min(h, cap)
        qd = qd.copy()
        if h > cap:
            speed = np.abs(qd)
            tau = np.minimum(h - cap, speed / self.amax)  # braking time so far
            q = q + np.sign(qd) * (speed * tau - 0.5 * self.amax * tau * tau)
            qd = np.sign(qd) * (speed - self.amax * tau)
        clipped = np.clip(q, self.lower, self.upper)
        qd[clipped != q] = 0.0
        return clipped, qd

    def settled(self) -> bool:
        """Holding, with the servo target at rest exactly on the held pose."""
        return self.holding and not self.qd_servo.any() and np.array_equal(self.q_servo, self._hold_q)

    def _advance_target(self, t: float, dt: float) -> np.ndarray:
        """Move the servo target one step dt [s] from time t [s] towards the reference; its velocity (n,) [rad/s].

        It moves with the reference, plus closing the gap to it no faster than braking (part of a_max) can stop at
        it; then within vmax, a_max and braking before the limits (JointBounds: the solver's own box).
        """
        ref, ref_qd = self._reference(t + dt)
        gap = ref - ref_qd * dt - self.q_servo  # what is left if the target moves with the reference
        b = self._servo_bounds
        want = ref_qd + np.sign(gap) * b.brake(np.abs(gap), dt, decel=CLOSING_DECEL)
        lb, ub = b.compute(self.q_servo, self.qd_servo, dt)
        v = np.minimum(np.maximum(want, lb), ub)
        self.qd_servo = v
        self.q_servo = self.q_servo + v * dt
        return v

    def _servo_step(self) -> None:
        d = self.robot.data
        dt = self.dt
        t = float(d.time)
        cfg = self.config
        if not self.holding and self._last_cmd_time is not None and t - self._last_cmd_time > cfg.watchdog:
            self.holding = True
            # Hold where the servo target can stop (braking at a_max), not where it is: no turning back.
            v = self.qd_servo
            self._hold_q = np.clip(self.q_servo + v * np.abs(v) / (2.0 * self.amax), self.lower, self.upper)
            self.counters.holds += 1
            log.info("watchdog: no command for %.0f ms, holding (t=%.3f s)", 1e3 * (t - self._last_cmd_time), t)
        if self.settled():
            # The target step would give v = 0 here (the braking lands on the held pose exactly): skipping it keeps
            # an idle sim cheap, since the 1 kHz loop runs with no commands too.
            ctrl = self.q_servo
        else:
            v = self._advance_target(t, dt)
            ctrl = self.q_servo + self._ff_gain * v if cfg.velocity_feedforward else self.q_servo
        if cfg.velocity_capped_servo:
            # The actuator force kp (ctrl - q) - kv qdot = kv (u - qdot) drives the joint towards the velocity
            # u = (ctrl - q) kp / kv: cap u at vmax (a drive's position loop saturating at its speed limit).
            # Below the cap ctrl is unchanged; at it the servo no longer pushes a lagging joint past vmax.
            q = d.qpos[self.robot.qpos_idx]
            lim = self.vmax * self._ff_gain
            ctrl = q + np.clip(ctrl - q, -lim, lim)
        d.ctrl[self.robot.act_idx] = ctrl
        mujoco.mj_step(self.robot.model, d)
        if d.ncon > self._ncon_max:
            self._ncon_max = int(d.ncon)
        self._check_velocity(d.qvel[self.robot.dof_idx])

    def _check_velocity(self, qd: np.ndarray) -> None:
        """Count a step whose simulated joint velocity ``qd`` (n,) [rad/s] exceeds the limits."""
        ratio = np.abs(qd) / np.maximum(self.vmax, 1e-9)
        i = int(np.argmax(ratio))
        c = self.counters
        if ratio[i] > VELOCITY_TOLERANCE:
            c.velocity_excess_steps += 1
        if ratio[i] > c.worst_velocity_ratio:
            c.worst_velocity_ratio = float(ratio[i])
            c.worst_velocity_joint = self.joint_names[i]

    def step_physics(self, n: int = 1) -> None:
        """Advance the physics by ``n`` steps of :attr:`dt` (watchdog checked every step)."""
        for _ in range(int(n)):
            self._servo_step()

    def advance(self, cmd: JointCommand | None, duration: float) -> bool:
        """Lock-step: apply ``cmd`` (if any) now, then simulate ``duration`` [s].

        Returns:
            Whether the command was applied.
        """
        ok = self.apply(cmd) if cmd is not None else False
        self.step_physics(max(1, round(duration / self.dt)))
        return ok

    # ------------------------------------------------------------------ output

    def frame_poses(self) -> dict[str, Pose]:
        """Achieved poses of the target frames in the pelvis frame (p [m], q wxyz)."""
        mujoco.mj_kinematics(self.robot.model, self.robot.data)  # xpos after mj_step lags qpos by one step
        out = {}
        for name in TARGET_NAMES:
            p, R = self.robot.frame_pose(name)
            out[name] = Pose(np.array(p, dtype=float), matrix_to_quat(R))
        return out

    def state(self) -> RobotState:
        """Current :class:`RobotState` (header = that of the last applied command)."""
        d = self.robot.data
        return RobotState(
            hdr=self.hdr,
            joints=list(self.joint_names),
            q=d.qpos[self.robot.qpos_idx].copy(),
            qd=d.qvel[self.robot.dof_idx].copy(),
            frames=self.frame_poses(),
            sim_time=float(d.time),
            solver_id=self.solver_id,
            holding=bool(self.holding),
        )

    def info(self) -> dict:
        """Servo configuration, for reports (JSON-able)."""
        return {
            "timestep_s": self.dt,
            "kp": sorted({float(k) for k in self.kp}),
            "kv": sorted({float(k) for k in self.kv}),
            "armature": sorted({float(a) for a in self.robot.model.dof_armature[self.robot.dof_idx]}),
            "velocity_feedforward": self.config.velocity_feedforward,
            "gravity_compensation": self.config.gravity_compensation,
            "contacts": self.config.contacts,
            "contact_exclude_hops": self.config.contact_exclude_hops,
            "max_extrapolation_s": self.config.max_extrapolation,
            "max_acceleration_rad_s2": float(np.max(self.amax)) if self.amax.size else math.nan,
            "watchdog_s": self.config.watchdog,
            "vmax_rad_s": float(np.max(self.vmax)) if self.vmax.size else math.nan,
        }
