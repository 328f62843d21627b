"""WheeledSimCore: the balancing TITA-PiPER in MuJoCo following 7-D JointCommands (no bus, no clock).

The same interface the sim service's :class:`~services.sim.node.SimNode` drives for the G1
(:meth:`apply`, :meth:`step_physics`, :meth:`state`, ...), so ``mimic sim --robot
models/tita_piper.toml`` runs it unchanged. A command's ``q``/``qd`` over the seven coordinates
(:data:`~services.solver.wbqp_accel.Q_NAMES`) become the :class:`~services.wbc.balance.Reference`
of the balance controller: held first-order between commands (for at most
``max_extrapolation``), the torso's acceleration estimated from consecutive commanded
velocities (low-passed). A command outside the planner's position limits or with unknown joints, NaN or a
wrong shape is refused (counted by reason, never applied). Without commands for ``watchdog``
seconds the robot holds where its reference got to, at rest, still balancing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import mujoco
import numpy as np

from services.sim.sim_core import CommandError, FollowerCore
from services.solver.wbqp_accel import Q_NAMES
from services.wbc.balance import BalanceController, Reference
from services.wbc.runner import measured_q, place_robot
from shared.messages import JointCommand, Pose, RobotState
from shared.robot.wheeled import build_wheeled_robot, planner_limits
from shared.rotations import matrix_to_quat

#: Tolerance past the planner's limits before a commanded coordinate is refused [m or rad].
LIMIT_TOL = 1e-6
#: Largest torso acceleration taken from two commands' velocities [m/s^2, rad/s^2].
MAX_BASE_ACC = 3.0
#: Time constant of the low-pass on that acceleration estimate [s].
ACC_FILTER_S = 0.05


@dataclass
class WheeledSimConfig:
    """timestep [s]; watchdog [s]; max_extrapolation [s]; solver_id followed."""

    timestep: float = 0.001
    watchdog: float = 0.1
    max_extrapolation: float = 0.05
    solver_id: str = "main"


class WheeledSimCore(FollowerCore):
    """MuJoCo TITA-PiPER with its balance controller (see the module docstring).

    Args:
        profile: wheeled profile name or path. config: settings.
    """

    def __init__(self, profile: str = "tita_piper", config: WheeledSimConfig | None = None):
        self.config = cfg = config or WheeledSimConfig()
        self.wheeled = build_wheeled_robot(profile)
        prof = self.wheeled.profile
        m = self.wheeled.mj_model
        m.opt.timestep = cfg.timestep
        d = mujoco.MjData(m)
        place_robot(self.wheeled, d, prof.start_base, prof.start_arm)
        self.robot = SimpleNamespace(model=m, data=d)  # what SimNode's renderer reads
        self.ctrl = BalanceController(m, prof.arm, prof.held, prof.wheels)
        self.ctrl.cfg.dt = cfg.timestep
        self.lower, self.upper = planner_limits(self.wheeled)
        q0 = measured_q(self.wheeled, d)[0]
        self._ref_q = q0.copy()
        self._ref_qd = np.zeros(7)
        self._ref_qdd = np.zeros(7)
        self._ref_t = 0.0
        self._last_cmd: tuple[float, np.ndarray] | None = None
        self._start_following(cfg.solver_id)
        self._hand = m.site(prof.hand_site).id

    def check(self, cmd: JointCommand) -> tuple[np.ndarray, np.ndarray]:
        """(q (7,), qd (7,)) of a valid command in Q_NAMES order; raises CommandError otherwise."""
        names = list(cmd.joints)
        if sorted(names) != sorted(Q_NAMES):
            raise CommandError("joint_names", f"a wheeled-robot command names exactly {list(Q_NAMES)}, got {names}")
        q = np.asarray(cmd.q, dtype=float).ravel()
        qd = np.asarray(cmd.qd, dtype=float).ravel()
        if q.shape != (7,) or qd.shape != (7,):
            raise CommandError("shape", f"7 coordinates but q {q.shape}, qd {qd.shape}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise CommandError("nan", "q or qd contains NaN or inf")
        order = [names.index(n) for n in Q_NAMES]
        q, qd = q[order], qd[order]
        bad = np.flatnonzero((q < self.lower - LIMIT_TOL) | (q > self.upper + LIMIT_TOL))
        if bad.size:
            j = int(bad[0])
            raise CommandError(
                "limits", f"{Q_NAMES[j]} = {q[j]:.4f} outside [{self.lower[j]:.4f}, {self.upper[j]:.4f}]"
            )
        return q, qd

    def apply(self, cmd: JointCommand, now: float | None = None) -> bool:
        """Take a command as the new reference; False (counted) if refused."""
        try:
            q, qd = self.check(cmd)
        except CommandError as exc:
            return self._reject(exc)
        now = self.time if now is None else float(now)
        if self._last_cmd is not None and cmd.t_cmd > self._last_cmd[0]:
            # The command carries no acceleration: a low-passed difference of the commanded
            # velocities (the raw one jumps with every mocap frame the planner reacts to).
            h = cmd.t_cmd - self._last_cmd[0]
            acc = np.clip((qd - self._last_cmd[1]) / h, -MAX_BASE_ACC, MAX_BASE_ACC)
            a = h / (ACC_FILTER_S + h)
            self._ref_qdd = (1.0 - a) * self._ref_qdd + a * acc
        self._last_cmd = (cmd.t_cmd, qd.copy())
        self._ref_q, self._ref_qd, self._ref_t = q, qd, now
        self._accepted(cmd, now)
        return True

    def _reference(self) -> Reference:
        t = self.time
        cfg = self.config
        if not self.holding and self._last_cmd_time is not None and t - self._last_cmd_time > cfg.watchdog:
            # No commands: hold where the reference got to, at rest (still balancing).
            self._ref_q = self._ref_q + self._ref_qd * min(t - self._ref_t, cfg.max_extrapolation)
            self._ref_qd = np.zeros(7)
            self._ref_qdd = np.zeros(7)
            self.holding = True
            self.counters.holds += 1
        h = 0.0 if self.holding else min(max(t - self._ref_t, 0.0), cfg.max_extrapolation)
        q = np.clip(self._ref_q + self._ref_qd * h, self.lower, self.upper)
        moving = not self.holding and h < cfg.max_extrapolation
        qd = self._ref_qd if moving else np.zeros(7)
        qdd = self._ref_qdd if moving else np.zeros(7)
        return Reference(q[:4], qd[:4], qdd[:4], q[4:], qd[4:])

    def step_physics(self, n: int = 1) -> None:
        """Advance n physics steps, the balance controller running every step."""
        m, d = self.robot.model, self.robot.data
        for _ in range(int(n)):
            self.ctrl.compute(d, self._reference())
            mujoco.mj_step(m, d)
            self._ncon_max = max(self._ncon_max, int(d.ncon))

    def state(self) -> RobotState:
        """RobotState: the 7 coordinates as measured, and the hand (Σa) as ``right_wrist`` in the start frame."""
        d = self.robot.data
        mujoco.mj_kinematics(self.robot.model, d)
        q, qd = measured_q(self.wheeled, d)
        R = d.site_xmat[self._hand].reshape(3, 3)
        hand = Pose(d.site_xpos[self._hand].copy(), matrix_to_quat(R))
        return RobotState(
            self.hdr, list(Q_NAMES), q, qd, {"right_wrist": hand}, self.time, self.solver_id, self.holding
        )

    def info(self) -> dict:
        return {
            "timestep_s": self.dt,
            "watchdog_s": self.config.watchdog,
            "robot": self.wheeled.profile.name,
            "balance": "LQR wheeled inverted pendulum + leg IK (services/wbc/balance.py)",
        }

    def pitch(self) -> float:
        """Torso pitch [rad] (for tests and reports)."""
        w, x, y, z = self.robot.data.qpos[3:7]
        return math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
