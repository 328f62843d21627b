"""Seed 002 section 5 in MuJoCo: the hand reaches along x to (2.0 m, 0.8 m) while the robot balances.

Loop, one tick per physics step Δt: the planner (:class:`~services.solver.wbqp_accel.WbqpAccel`)
plans q̈ from its state, integrates it (eq. 7) into the reference the
:class:`~services.wbc.balance.BalanceController` turns into torques; MuJoCo steps. The
planner's q_pre, q̇_pre are its own prediction (eq. 7), not the measured robot as in the seed:
fed the measured torso position, the loop diverges (a wheeled pendulum first rolls backwards to
lean forwards; the hand PD reads that as error and the planner pushes harder). The balance
controller closes the loop on the torso instead.

The hand's desired motion is a minimum-jerk (quintic) path from its start to the goal over
``duration`` seconds, then a hold; "steady state" is the last ``steady_window`` seconds.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from services.solver.wbqp_accel import WbqpAccel, WbqpConfig
from services.wbc.balance import BalanceConfig, BalanceController, Reference, leg_ik, yaw_pitch_roll
from shared.kinematics.mobile_arm import ARM, BASE, NQ
from shared.robot.wheeled import WheeledRobot, build_wheeled_robot, planner_limits

log = logging.getLogger("mimic.wbc")

#: Torso-centre height [m] under which the robot counts as fallen (it stands at 0.30-0.46 m).
FALLEN_Z = 0.15
#: Tolerance [rad or m] past a Table 2 joint range before a measured joint counts as a violation.
RANGE_TOL = 1e-3


@dataclass
class WbcEvalConfig:
    """Experiment settings.

    Attributes:
        goal_x: hand goal x in the world Σw [m] (seed: 2.0; y stays at the start).
        goal_z: hand goal z in the world Σw [m] (seed: 0.8).
        duration: time of the minimum-jerk reach [s].
        hold: time held at the goal afterwards [s].
        settle: balancing at the start pose before the reach [s].
        steady_window: final span where the steady-state error is taken [s].
        planner: the planner's settings. balance: the balance controller's.
    """

    goal_x: float = 2.0
    goal_z: float = 0.8
    duration: float = 8.0
    hold: float = 4.0
    settle: float = 1.0
    steady_window: float = 2.0
    planner: WbqpConfig = field(default_factory=lambda: WbqpConfig(dt=0.001))
    balance: BalanceConfig = field(default_factory=BalanceConfig)

    def __post_init__(self) -> None:
        if self.steady_window > self.hold:
            raise ValueError("steady_window must not exceed hold")


def min_jerk(p0: np.ndarray, p1: np.ndarray, T: float, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk path p0 -> p1 (3,) over T [s]: (p, v, a) at t [s] (held before 0 and after T)."""
    s = min(max(t / T, 0.0), 1.0)
    d = p1 - p0
    if t <= 0.0 or t >= T:
        return (p0 if t <= 0.0 else p1).copy(), np.zeros(3), np.zeros(3)
    pos = 10 * s**3 - 15 * s**4 + 6 * s**5
    vel = (30 * s**2 - 60 * s**3 + 30 * s**4) / T
    acc = (60 * s - 180 * s**2 + 120 * s**3) / (T * T)
    return p0 + d * pos, d * vel, d * acc


def place_robot(robot: WheeledRobot, d: mujoco.MjData, base: np.ndarray, arm: np.ndarray) -> None:
    """Put the robot at base (4,) [x, y, z, α], arm (3,) [rad], held joints, legs under the COM, at rest."""
    m = robot.mj_model
    prof = robot.profile
    d.qpos[:] = 0.0
    d.qvel[:] = 0.0
    d.qpos[0:3] = base[:3]
    d.qpos[3:7] = (math.cos(base[3] / 2), 0.0, 0.0, math.sin(base[3] / 2))
    for name, v in zip(prof.arm, arm):
        d.qpos[m.jnt_qposadr[m.joint(name).id]] = v
    for name, v in prof.held.items():
        d.qpos[m.jnt_qposadr[m.joint(name).id]] = v
    r = float(m.geom_size[m.geom(f"{prof.wheels[0]}_geom").id][0])
    length = float(abs(m.body("left_crus").pos[2]))
    offset = 0.0
    for _ in range(10):  # fixed point: the legs move the COM they are placed under
        hp, kn = leg_ik(offset, -(base[2] - r), length)
        for s in ("left", "right"):
            d.qpos[m.jnt_qposadr[m.joint(f"{s}_hip_pitch").id]] = hp
            d.qpos[m.jnt_qposadr[m.joint(f"{s}_knee").id]] = kn
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        com = d.subtree_com[robot.mj_model.body("torso").id]
        offset = float((com[:2] - base[:2]) @ np.array([math.cos(base[3]), math.sin(base[3])]))
    mujoco.mj_forward(m, d)


def measured_q(robot: WheeledRobot, d: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """(q (7,), q̇ (7,)) of the planner's coordinates, measured on the MuJoCo robot."""
    m = robot.mj_model
    yaw, _, _ = yaw_pitch_roll(d.qpos[3:7])
    q = np.zeros(NQ)
    qd = np.zeros(NQ)
    q[:3] = d.qpos[:3]
    q[3] = yaw
    qd[:3] = d.qvel[:3]
    qd[3] = d.qvel[5]
    for k, name in enumerate(robot.profile.arm):
        j = m.joint(name).id
        q[4 + k] = d.qpos[m.jnt_qposadr[j]]
        qd[4 + k] = d.qvel[m.jnt_dofadr[j]]
    return q, qd


def run_reach(config: WbcEvalConfig | None = None, robot: WheeledRobot | str = "tita_piper") -> dict:
    """Run the section-5 reach; returns {"metrics": {...}, "trace": {name: array}, "info": {...}}."""
    cfg = config or WbcEvalConfig()
    robot = robot if isinstance(robot, WheeledRobot) else build_wheeled_robot(robot)
    prof = robot.profile
    m = robot.mj_model
    m.opt.timestep = cfg.planner.dt
    d = mujoco.MjData(m)
    place_robot(robot, d, prof.start_base, prof.start_arm)
    ctrl = BalanceController(m, prof.arm, prof.held, prof.wheels, config=cfg.balance)
    ctrl.cfg.dt = cfg.planner.dt
    lo, hi = planner_limits(robot)
    planner = WbqpAccel(robot.kin, lo, hi, cfg.planner)
    q = measured_q(robot, d)[0]
    q_plan, qd_plan, qdd_plan = q.copy(), np.zeros(NQ), np.zeros(NQ)

    def reference() -> Reference:
        return Reference(
            q_plan[BASE].copy(), qd_plan[BASE].copy(), qdd_plan[BASE].copy(), q_plan[ARM].copy(), qd_plan[ARM].copy()
        )

    # Start in dynamic balance: hold the start pose.
    for _ in range(round(cfg.settle / cfg.planner.dt)):
        ctrl.compute(d, reference())
        mujoco.mj_step(m, d)
    hand_site = m.site(prof.hand_site).id
    p0 = robot.kin.hand(q_plan)
    goal = np.array([cfg.goal_x, p0[1], cfg.goal_z])
    n = round((cfg.duration + cfg.hold) / cfg.planner.dt)
    tr = {k: np.zeros((n, 3)) for k in ("p_des", "p_sim", "p_plan")}
    tr.update({k: np.zeros(n) for k in ("t", "vx_plan", "vx_sim", "pitch", "roll", "solve_ms", "cpu_ms", "ee_res")})
    tr["q_plan"] = np.zeros((n, NQ))
    statuses: dict[str, int] = {}
    fell_at = None
    violations = 0
    viol_detail: dict[str, int] = {}
    jranges = [(j, m.jnt_qposadr[j], m.jnt_range[j]) for j in range(m.njnt) if m.jnt_limited[j]]
    for i in range(n):
        t = i * cfg.planner.dt
        p_d, v_d, a_d = min_jerk(p0, goal, cfg.duration, t)
        res = planner.solve(q_plan, qd_plan, p_d, v_d, a_d)
        statuses[res.status] = statuses.get(res.status, 0) + 1
        qdd_plan, q_plan, qd_plan = res.qdd, res.q_next, res.qd_next  # eq. 7, timed in res.solve_ms
        if np.any(q_plan < planner.lower - 1e-9) or np.any(q_plan > planner.upper + 1e-9):
            violations += 1
            viol_detail["plan"] = viol_detail.get("plan", 0) + 1
        ctrl.compute(d, reference())
        mujoco.mj_step(m, d)
        if not np.all(np.isfinite(d.qpos)) or d.qpos[2] < FALLEN_Z:
            # The robot fell (or the physics diverged): stop, and say so in the report.
            fell_at = t
            violations += 1
            viol_detail["fell"] = 1
            log.error("robot fell or diverged at t = %.3f s: stopping the run", t)
            n = i
            tr = {k: v[:n] for k, v in tr.items()}
            break
        for j, adr, (a, b) in jranges:
            if not a - RANGE_TOL <= d.qpos[adr] <= b + RANGE_TOL:
                violations += 1
                name = m.joint(j).name
                viol_detail[name] = viol_detail.get(name, 0) + 1
        _, pitch, roll = yaw_pitch_roll(d.qpos[3:7])
        tr["t"][i] = t
        tr["p_des"][i] = p_d
        tr["p_sim"][i] = d.site_xpos[hand_site]
        tr["p_plan"][i] = robot.kin.hand(q_plan)
        tr["vx_plan"][i] = qd_plan[0]
        tr["vx_sim"][i] = d.qvel[0]
        tr["pitch"][i] = pitch
        tr["roll"][i] = roll
        tr["solve_ms"][i] = res.solve_ms
        tr["cpu_ms"][i] = res.cpu_ms
        tr["ee_res"][i] = res.ee_residual
        tr["q_plan"][i] = q_plan
    if n == 0:
        raise RuntimeError("the robot fell before the first planner tick")
    err = np.linalg.norm(tr["p_sim"] - tr["p_des"], axis=1) * 1e3
    steady = tr["t"] >= cfg.duration + cfg.hold - cfg.steady_window
    if not steady.any():  # fell before the steady window: the last sample stands in (fell_at_s says so)
        steady[-1] = True
    ms = tr["solve_ms"]
    metrics = {
        "ee_err_mm": {"mean": float(err.mean()), "max": float(err.max()), "steady_max": float(err[steady].max())},
        "torso_vel_err_mps": {"max": float(np.max(np.abs(tr["vx_sim"] - tr["vx_plan"])))},
        "torso_att_rad": {"max": float(np.max(np.maximum(np.abs(tr["pitch"]), np.abs(tr["roll"]))))},
        "solve_ms": {
            "mean": float(ms.mean()),
            "p50": float(np.percentile(ms, 50)),
            "p99": float(np.percentile(ms, 99)),
        },
        "violations": int(violations),
    }
    steady_xz = np.abs(tr["p_sim"] - tr["p_des"])[steady] * 1e3
    cpu = tr["cpu_ms"]
    info = {
        "statuses": statuses,
        "solve_cpu_ms": {
            "mean": float(cpu.mean()),
            "p50": float(np.percentile(cpu, 50)),
            "p99": float(np.percentile(cpu, 99)),
        },
        "violations_by": viol_detail,
        "ee_steady_max_mm_x": float(steady_xz[:, 0].max()),
        "ee_steady_max_mm_z": float(steady_xz[:, 2].max()),
        "plan_ee_err_mm_max": float(np.max(np.linalg.norm(tr["p_plan"] - tr["p_des"], axis=1)) * 1e3),
        "torso_travel_m": float(tr["q_plan"][-1, 0] - tr["q_plan"][0, 0]),
        "fell_at_s": fell_at,
        "hand_start": p0.tolist(),
        "hand_goal": goal.tolist(),
        "final_q_plan": tr["q_plan"][-1].tolist(),
        "dt_s": cfg.planner.dt,
        "qp": cfg.planner.qp,
    }
    return {"metrics": metrics, "trace": tr, "info": info}
