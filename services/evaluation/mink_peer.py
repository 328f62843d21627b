"""mink's weighted ``solve_ik`` as an evaluation algorithm ("mink"): the peer users would pick instead.

mink is the differential IK that GMR (the retargeter most users pick) is built on. Here it gets the
same targets as our solvers, through the same :class:`~services.solver.targets.TargetTracker` (each
tick: the newest frame, extrapolated with its velocity to the instant the command is for), at the
same rate, on the MuJoCo model of the same robot, with the equivalent weighted problem: wrist
FrameTasks (position cost 1, orientation cost from :class:`SolverConfig`: mink's costs weigh the errors,
ours the velocity rows, at equal gains the same trade of errors), elbow position-only
FrameTasks, a posture task towards the rest pose, and mink's ConfigurationLimit (with the profile's
limit margin) and VelocityLimit (the profile's joint speed cap). Its commands are scored exactly
like ours.

"mink-limited" is the same peer held to the limits our solvers plan within: each tick its joint velocities
are clipped into the :class:`~services.solver.bounds.JointBounds` box of the robot's position (with braking),
velocity and acceleration limits before they are integrated. mink itself has no acceleration limit, so plain
"mink" may command steps no motor makes (``acceleration_violations`` in the eval JSON counts them); the
limited peer compares the two methods at equal limits.

mink is an optional dependency (the ``eval`` and ``dev`` extras); :func:`require_mink` turns its
absence into a one-line error.
"""

from __future__ import annotations

import time

import numpy as np

from services.solver.bounds import JointBounds
from services.solver.core import SolverConfig
from services.solver.targets import TargetTracker
from shared.messages import TARGET_NAMES, Header, JointCommand, TaskTargets
from shared.robot.pinocchio_model import RobotModel
from shared.targets import WRISTS

#: Algorithm name of the peer in ``mimic eval --algos``.
MINK = "mink"
#: The peer with its velocities clipped into our solvers' limit box.
MINK_LIMITED = "mink-limited"
#: Every peer name ``mimic eval --algos`` takes.
PEERS = (MINK, MINK_LIMITED)


class MinkMissingError(RuntimeError):
    """mink (or its QP solver) is not installed."""


def require_mink():
    """Import mink, or raise :class:`MinkMissingError` with the install hint."""
    try:
        import mink
    except ImportError as exc:
        hint = "install with: pip install -e '.[eval]'"
        raise MinkMissingError(f"--algos mink needs the mink package ({exc}); {hint}") from None
    return mink


class MinkPeer:
    """``step(targets, measured_q, t) -> JointCommand`` like :class:`SolverCore`, solved by mink.

    Args:
        robot: reduced Pinocchio model whose joints are commanded (their order is the command's).
        rate: control rate [Hz].
        solver: qpsolvers backend name for ``mink.solve_ik``.
        limited: clip mink's joint velocities into the position/velocity/acceleration box of ``robot``
            (``JointBounds``) before integrating ("mink-limited").
        config: our solvers' settings (default: ``SolverConfig()``); the peer reads the target tracking
            (horizon, timeout, acceleration) and the task costs from it, so it gets the targets ours get.
    """

    def __init__(
        self,
        robot: RobotModel,
        rate: float = 500.0,
        solver: str = "daqp",
        limited: bool = False,
        config: SolverConfig | None = None,
    ):
        mink = require_mink()
        from shared.robot.mujoco_model import build_mujoco_robot

        self.mink = mink
        self.robot = robot
        self.dt = 1.0 / rate
        self.solver = solver
        cfg = SolverConfig() if config is None else config
        #: the solver settings the tracker and the eval read (as :class:`SolverCore` has them)
        self.config = cfg
        self.counts: dict[str, int] = {}
        self.tracker = TargetTracker.for_solver(cfg)
        mj = build_mujoco_robot(robot.profile, joint_names=robot.joint_names)
        self.mj = mj
        model = mj.model
        self.configuration = mink.Configuration(model)
        self.configuration.update(mj.data.qpos.copy())
        prof = robot.profile
        base = mj.data.body(mj.body_ids["__base__"])
        self.T_world_base = mink.SE3.from_rotation_and_translation(
            mink.SO3.from_matrix(base.xmat.reshape(3, 3).copy()), base.xpos.copy()
        )
        #: the wrists' orientation cost when their target carries a rotation (``use_rotation``), as our solvers
        self.orientation_cost = cfg.wrist_orientation_cost
        # A wrist whose orientation frame is another link (``[orientation_frames]``: the G1's hand, past its wrist
        # point) gets two tasks, as in our solvers: the position on one frame, the orientation on the other.
        self.rotation_tasks = {
            name: mink.FrameTask(frame, "body", position_cost=0.0, orientation_cost=cfg.wrist_orientation_cost)
            for name, frame in prof.split_orientation_frames.items()
            if name in WRISTS
        }
        self.tasks = {
            name: mink.FrameTask(
                prof.frames[name],
                "body",
                position_cost=cfg.wrist_position_cost if name in WRISTS else cfg.elbow_cost,
                orientation_cost=cfg.wrist_orientation_cost
                if name in WRISTS and name not in self.rotation_tasks
                else 0.0,
            )
            for name in TARGET_NAMES
        }
        self.posture = mink.PostureTask(model, cost=cfg.posture_cost)
        self.posture.set_target_from_configuration(self.configuration)
        # the controlled joints' speed caps; the others (the legs, and the waist of an arms-only run) stay where they
        # are, as on the robot this one is compared with: a free waist moved mink's arms where our kinematics (the
        # waist at rest) did not see them, 8.5 cm of wrist error with --no-waist (session 21)
        vmax = dict.fromkeys((model.joint(j).name for j in range(model.njnt)), 0.0)
        vmax |= {n: float(v) for n, v in zip(robot.joint_names, robot.vmax)}
        self.limits = [
            mink.ConfigurationLimit(model, min_distance_from_limits=float(prof.limit_margin)),
            mink.VelocityLimit(model, vmax),
        ]
        self.qpos_idx = mj.qpos_idx
        self.dof_idx = mj.dof_idx
        #: the box of the limits our solvers keep (None: mink as users run it)
        self.bounds = JointBounds(robot.lower, robot.upper, robot.vmax, robot.amax) if limited else None
        self._qd_prev = np.zeros(len(robot.joint_names))
        self.q_rest = robot.q_rest.copy()

    def step(self, targets: TaskTargets | None, measured_q: np.ndarray | None, t: float) -> JointCommand:
        """One tick at time t [s]: the tasks take the tracker's targets at t + dt, mink solves, q integrates."""
        t0 = time.perf_counter()
        mink = self.mink
        if targets is not None:
            self.tracker.update(targets, t)
        conf = self.configuration
        status = "init"
        qd_all = np.zeros(conf.model.nv)
        if self.tracker.started:
            tasks = [self.posture]
            for name, task in self.tasks.items():
                s = self.tracker.sample(name, t + self.dt)
                if s is None:
                    continue  # no target yet (a clip whose marker set lacks it): mink would raise
                T = self.T_world_base @ mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(s.R), s.p)
                task.set_target(T)
                tasks.append(task)
                if name in WRISTS:
                    rot = self.rotation_tasks.get(name, task)
                    rot.set_orientation_cost(self.orientation_cost if s.use_rotation else 0.0)
                    if rot is not task:
                        rot.set_target(T)
                        tasks.append(rot)
            qd_all = mink.solve_ik(conf, tasks, self.dt, self.solver, limits=self.limits)
            if self.bounds is not None:
                lb, ub = self.bounds.compute(conf.q[self.qpos_idx], self._qd_prev, self.dt)
                qd_all[self.dof_idx] = np.clip(qd_all[self.dof_idx], lb, ub)
                self._qd_prev = qd_all[self.dof_idx].copy()
            conf.integrate_inplace(qd_all, self.dt)
            status = "ok"
        q = conf.q[self.qpos_idx].copy()
        qd = qd_all[self.dof_idx].copy()
        return JointCommand(
            hdr=self.tracker.hdr if self.tracker.started else Header(0, 0.0, 0),
            solver_id="eval",
            algo=MINK_LIMITED if self.bounds is not None else MINK,
            joints=list(self.robot.joint_names),
            q=q,
            qd=qd,
            residuals=[],
            solve_ms=(time.perf_counter() - t0) * 1e3,
            status=status,
            t_cmd=t,
        )
