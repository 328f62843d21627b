"""WbqpCore: ``wbqp-accel`` behind the solver's command contract (TaskTargets in, JointCommand out), no bus.

The operator's right hand drives the gripper: the ``right_wrist`` target (position and
velocity, in the robot's base frame, here the world frame Σw the robot started in) is the
hand's desired motion for seed 002's planner. Each :meth:`WbqpCore.step` samples the target at
the tick time, plans q̈, integrates it (eq. 7, inside the planner's tick) and returns a
JointCommand whose joints are the seven generalised coordinates
(:data:`~services.solver.wbqp_accel.Q_NAMES`): ``q`` [m, rad], ``qd`` [m/s, rad/s],
``residuals = [||J_a q̈ - b||]`` [m/s^2].

Status: ``init`` before the first targets (the start pose is held), ``ok`` (the hand equality
held), ``infeasible`` (section 4.1 fallback; the reason gives the residual), ``held`` (targets
stale or invalid: the last target is held at rest), ``failed`` (no QP solution: braking within
the limits). Every command lies within the planner's position limits.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from services.solver.reference_filter import ReferenceFilter
from services.solver.targets import TargetTracker
from services.solver.wbqp_accel import Q_NAMES, WbqpAccel, WbqpConfig
from shared.messages import Header, JointCommand, TaskTargets
from shared.robot.wheeled import WheeledRobot, planner_limits


@dataclass
class WbqpCoreConfig:
    """Settings: ``solver_id``; ``target`` driving the hand; target ``horizon``/``timeout`` [s]; the planner's.

    ``ref_omega`` [rad/s] and ``ref_acc_max`` [m/s^2]: the reference filter between the targets and
    the planner (:mod:`services.solver.reference_filter`; ``ref_omega = 0`` turns it off: the
    planner then gets the sampled targets as they are, which excite a torso/arm oscillation).
    """

    solver_id: str = "main"
    target: str = "right_wrist"
    horizon: float = 0.05
    timeout: float = 0.5
    planner: WbqpConfig = field(default_factory=WbqpConfig)
    ref_omega: float = 6.0
    ref_acc_max: float = 2.0


class WbqpCore:
    """Fixed-rate 7-D commands for a wheeled-legged arm robot (see the module docstring).

    Args:
        robot: the wheeled robot (its profile gives the start pose and limits).
        config: settings (the control period is ``config.planner.dt``).
    """

    def __init__(self, robot: WheeledRobot, config: WbqpCoreConfig | None = None):
        self.robot = robot
        self.config = cfg = config or WbqpCoreConfig()
        lo, hi = planner_limits(robot)
        self.planner = WbqpAccel(robot.kin, lo, hi, cfg.planner)
        self.tracker = TargetTracker(cfg.horizon, cfg.timeout, names=(cfg.target,))
        self.q = np.r_[robot.profile.start_base, robot.profile.start_arm].astype(float)
        self.qd = np.zeros(len(Q_NAMES))
        self.dt = cfg.planner.dt
        self.ref = ReferenceFilter(cfg.ref_omega, cfg.ref_acc_max) if cfg.ref_omega > 0 else None

    def step(self, targets: TaskTargets | None, t: float) -> JointCommand:
        """One tick at solver time t [s] with the newest targets since the last tick (or None)."""
        t0 = time.perf_counter()
        cfg = self.config
        if targets is not None:
            self.tracker.update(targets, t)
        s = self.tracker.sample(cfg.target, t) if self.tracker.started else None
        if s is None:
            self.qd[:] = 0.0
            return self._command("init", [], 0, f"waiting for a valid {cfg.target} target", t0, t)
        stale = self.tracker.stale(t)
        v_d = np.zeros(3) if (stale or s.held) else s.v
        if self.ref is None:
            res = self.planner.solve(self.q, self.qd, s.p, v_d)
        else:
            if self.ref.p is None:  # start from where the hand is, not with a jump to the first target
                self.ref.reset(self.planner.kin.evaluate(self.q, self.qd)[0])
            p_r, v_r, a_r = self.ref.step(s.p, v_d, self.dt)
            res = self.planner.solve(self.q, self.qd, p_r, v_r, a_r)
        self.q, self.qd = res.q_next, res.qd_next
        status, reason = res.status, res.reason
        if status == "ok" and (stale or s.held):
            status = "held"
            reason = "targets stale: holding the last one" if stale else f"{cfg.target} invalid: holding the last one"
        return self._command(status, [res.ee_residual], res.iters, reason, t0, t)

    def _command(self, status: str, residuals: list[float], iters: int, reason: str, t0: float, t: float):
        return JointCommand(
            hdr=self.tracker.hdr if self.tracker.started else Header(0, 0.0, 0),
            solver_id=self.config.solver_id,
            algo=WbqpAccel.name,
            joints=list(Q_NAMES),
            q=self.q.copy(),
            qd=self.qd.copy(),
            residuals=residuals,
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status=status,
            iters=int(iters),
            reason=reason,
            t_cmd=t,
        )
