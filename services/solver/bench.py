"""``mimic bench solvers``: per-tick solver time, every algorithm, 14 and 17 DoF, PIQP and DAQP, and mink.

A tick is one full :meth:`SolverCore.step`: target sampling, task construction
(one Pinocchio pass, every Jacobian), the solve, integration and smoothing.
Targets come from real clips run through the retarget service's logic
(``--clip FILE.bvh``, repeatable), from a ``.npz`` file (``--targets``) or,
by default, from forward kinematics of a smooth joint trajectory sampled at
mocap rate (100 Hz), velocities included. Frames are fed to the 500 Hz
solver at their own time stamps.

``.npz`` layout: ``t`` (F,) [s] and, per target name ``left_wrist``,
``right_wrist``, ``left_elbow``, ``right_elbow``: ``<name>_p`` (F, 3) [m] and
``<name>_q`` (F, 4) wxyz in the pelvis frame, optional ``<name>_v`` (F, 3)
[m/s] and ``<name>_w`` (F, 3) [rad/s].

mink (``solve_ik``) runs on the MuJoCo model of the same robot
(``build_mujoco_robot``, all of its joints: legs included, held by the
posture task) with the equivalent weighted problem: wrist FrameTasks, elbow
position-only FrameTasks, a posture task, ConfigurationLimit and
VelocityLimit, on the same frames.
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from services.solver.cli import add_switches, switch_values
from services.solver.core import SolverConfig, SolverCore
from services.solver.registry import ALGORITHMS, USES_QP
from shared.messages import Header, Target, TaskTargets
from shared.report import emit_json
from shared.robot.pinocchio_model import RobotModel, build_robot_model
from shared.rotations import matrix_to_quat
from shared.targets import TARGET_NAMES

log = logging.getLogger("mimic.bench.solvers")

#: Seed 000, Fig. 9(f): per-solve time on an i7-12700H [ms].
PAPER_MS = {"hqp-nullspace": 38.9, "hqp-original": 83.9, "wqp": 136.0}
MOCAP_RATE = 100.0


def synthetic_targets(robot: RobotModel, seconds: float, seed: int = 0) -> list[TaskTargets]:
    """Targets at 100 Hz by forward kinematics of a smooth joint trajectory (with velocities)."""
    rng = np.random.default_rng(seed)
    n = robot.nq
    amp = rng.uniform(0.2, 0.6, n)
    freq = rng.uniform(0.2, 0.8, n) * 2 * np.pi
    phase = rng.uniform(0, 2 * np.pi, n)
    centre = 0.5 * (robot.lower + robot.upper) * 0.3 + 0.7 * robot.q_rest

    def q_of(t: float) -> np.ndarray:
        return robot.clip(centre + amp * np.sin(freq * t + phase))

    out = []
    h = 1e-4
    for i in range(int(seconds * MOCAP_RATE)):
        t = i / MOCAP_RATE
        now, ahead, behind = robot.frame_poses(q_of(t)), robot.frame_poses(q_of(t + h)), robot.frame_poses(q_of(t - h))
        targets = {}
        for name in TARGET_NAMES:
            v = (ahead[name][0] - behind[name][0]) / (2 * h)
            w = pin.log3(ahead[name][1] @ behind[name][1].T) / (2 * h)
            targets[name] = Target(now[name][0].copy(), matrix_to_quat(now[name][1]), v, w)
        out.append(TaskTargets(Header(i, t), targets))
    return out


def load_targets(path: Path) -> list[TaskTargets]:
    """Targets from an ``.npz`` file (layout in the module docstring)."""
    data = np.load(path)
    if "t" not in data:
        raise ValueError(f"{path}: missing array 't'; arrays: {sorted(data.files)}")
    t = data["t"]
    out = []
    zero = np.zeros((len(t), 3))
    for i in range(len(t)):
        targets = {}
        for name in TARGET_NAMES:
            if f"{name}_p" not in data:
                continue
            q = data[f"{name}_q"][i] if f"{name}_q" in data else np.array([1.0, 0, 0, 0])
            targets[name] = Target(
                data[f"{name}_p"][i].astype(float),
                q / np.linalg.norm(q),
                data.get(f"{name}_v", zero)[i].astype(float),
                data.get(f"{name}_w", zero)[i].astype(float),
            )
        if not targets:
            raise ValueError(f"{path}: no <target>_p arrays for any of {TARGET_NAMES}")
        out.append(TaskTargets(Header(i, float(t[i])), targets))
    return out


def clip_targets(paths: list[Path]) -> list[TaskTargets]:
    """Targets of real recorded clips through the retarget service's pure logic, back to back in time."""
    from services.ingest.clip import load_clip
    from services.retarget.retargeter import RetargetConfig, Retargeter

    out: list[TaskTargets] = []
    t_offset = 0.0
    retargeter = None
    for path in paths:
        clip = load_clip(path)
        base = Retargeter(RetargetConfig()) if retargeter is None else retargeter
        retargeter = Retargeter(RetargetConfig(), workspace=base.workspace, robot=base.robot)
        for i in range(clip.n_frames):
            msg = retargeter.step(clip.frame(i, seq=len(out) + 1))
            if msg is not None:
                msg.hdr.stamp = t_offset + i / clip.fps
                out.append(msg)
        t_offset += clip.n_frames / clip.fps + 0.5
    if not out:
        raise ValueError(f"no targets from clips {paths}")
    return out


def _percentiles(ms: np.ndarray) -> dict[str, float]:
    return {
        "p50": round(float(np.percentile(ms, 50)), 4),
        "p95": round(float(np.percentile(ms, 95)), 4),
        "p99": round(float(np.percentile(ms, 99)), 4),
        "max": round(float(ms.max()), 4),
    }


def time_solver(
    robot: RobotModel,
    algo: str,
    qp: str,
    frames: list[TaskTargets],
    rate: float,
    warmup: int,
    switches: dict[str, bool] | None = None,
) -> dict:
    """Run SolverCore over the frames at ``rate`` Hz; per-tick wall time of ``step``.

    ``switches``: ``SolverConfig`` on/off fields to set (``cli.SWITCHES``: the damper rows, the projection of wrist
    targets onto the trunk's surface; absent: ``SolverConfig``'s default, as shipped)."""
    cfg = replace(SolverConfig(algo=algo, qp=qp, rate=rate), **(switches or {}))
    core = SolverCore(robot, cfg)
    stamps = np.array([f.hdr.stamp for f in frames]) - frames[0].hdr.stamp
    ticks = int(stamps[-1] * rate) + 1
    ms = np.empty(ticks)
    cpu = np.empty(ticks)
    statuses: dict[str, int] = {}
    j = 0
    for k in range(ticks):
        t = k / rate
        msg = None
        while j < len(frames) and stamps[j] <= t + 1e-9:  # newest frame due by now (older ones skipped)
            msg = frames[j]
            j += 1
        c0 = time.thread_time_ns()
        t0 = time.perf_counter()
        cmd = core.step(msg, None, t)
        ms[k] = (time.perf_counter() - t0) * 1e3
        cpu[k] = (time.thread_time_ns() - c0) * 1e-6
        if k >= warmup:
            statuses[cmd.status] = statuses.get(cmd.status, 0) + 1
    ms = ms[warmup:]
    return {
        "algo": algo,
        "qp": qp if algo in USES_QP else "none",
        "dof": robot.nq,
        "self_collision": core.collision is not None,
        "trunk_projection": core.trunk_projection is not None,
        "ticks": int(ms.size),
        "tick_ms": _percentiles(ms),
        # CPU time of this thread: what the tick costs without the time other processes took the core.
        "tick_cpu_ms": _percentiles(cpu[warmup:]),
        "qp_calls_per_tick": round(core.counts["qp_calls"] / ticks, 3),
        "statuses": statuses,
        "counts": dict(core.counts),
    }


def time_mink(robot: RobotModel, frames: list[TaskTargets], rate: float, warmup: int, solver: str) -> dict:
    """mink.solve_ik on the same frames and the equivalent weighted problem."""
    import mink

    from shared.robot.mujoco_model import build_mujoco_robot

    mj = build_mujoco_robot(robot.profile, joint_names=robot.joint_names)
    model = mj.model
    config = mink.Configuration(model)
    config.update(mj.data.qpos.copy())
    prof = robot.profile
    base = mj.data.body(mj.body_ids["__base__"])
    T_world_base = mink.SE3.from_rotation_and_translation(
        mink.SO3.from_matrix(base.xmat.reshape(3, 3).copy()), base.xpos.copy()
    )
    cfg = SolverConfig()
    tasks = {}
    for name in TARGET_NAMES:
        wrist = "wrist" in name
        tasks[name] = mink.FrameTask(
            prof.frames[name],
            "body",
            position_cost=cfg.wrist_position_cost if wrist else cfg.elbow_cost,
            orientation_cost=cfg.wrist_orientation_cost if wrist else 0.0,
        )
    posture = mink.PostureTask(model, cost=cfg.posture_cost)
    posture.set_target_from_configuration(config)
    vmax = {model.joint(j).name: min(4.0, 4.0) for j in range(model.njnt)}
    limits = [mink.ConfigurationLimit(model), mink.VelocityLimit(model, vmax)]
    all_tasks = [*tasks.values(), posture]
    dt = 1.0 / rate
    stamps = np.array([f.hdr.stamp for f in frames]) - frames[0].hdr.stamp
    ticks = int(stamps[-1] * rate) + 1
    ms = np.empty(ticks)
    cpu = np.empty(ticks)
    j = 0
    for k in range(ticks):
        c0 = time.thread_time_ns()
        t0 = time.perf_counter()
        msg = None
        while j < len(frames) and stamps[j] <= k * dt + 1e-9:
            msg = frames[j]
            j += 1
        if msg is not None:
            for name, tg in msg.targets.items():
                if name in tasks:
                    T = mink.SE3.from_rotation_and_translation(mink.SO3(wxyz=tg.q), tg.p)
                    tasks[name].set_target(T_world_base @ T)
        vel = mink.solve_ik(config, all_tasks, dt, solver, limits=limits)
        config.integrate_inplace(vel, dt)
        ms[k] = (time.perf_counter() - t0) * 1e3
        cpu[k] = (time.thread_time_ns() - c0) * 1e-6
    ms = ms[warmup:]
    return {
        "solver": solver,
        "dof": int(model.nv),
        "ticks": int(ms.size),
        "tick_ms": _percentiles(ms),
        "tick_cpu_ms": _percentiles(cpu[warmup:]),
    }


def run_bench(
    frames_by_dof: dict[int, list[TaskTargets]],
    robots: dict[int, RobotModel],
    algos: list[str],
    qps: list[str],
    rate: float,
    warmup: int,
    mink_solver: str | None,
    switches: dict[str, bool] | None = None,
) -> dict:
    """All combinations; returns the JSON-ready report (``switches`` as in :func:`time_solver`)."""
    load_before = os.getloadavg()[0]
    results = []
    for dof, robot in robots.items():
        for algo in algos:
            for qp in qps if algo in USES_QP else qps[:1]:
                res = time_solver(robot, algo, qp, frames_by_dof[dof], rate, warmup, switches)
                ms = res["tick_ms"]
                log.info("%-15s %-5s %2d DoF  p50 %.4f ms  p99 %.4f ms", algo, res["qp"], dof, ms["p50"], ms["p99"])
                results.append(res)
    report: dict = {
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count(),
            "python": platform.python_version(),
            # Other processes share these cores; the load average says how much they took.
            "load_avg_1m_before": round(load_before, 2),
            "load_avg_1m_after": round(os.getloadavg()[0], 2),
        },
        "rate_hz": rate,
        "results": results,
        "paper_ms": PAPER_MS,
    }
    big = max(robots)
    # The shipped configuration's backend when it was run.
    shipped = SolverConfig().qp if SolverConfig().qp in qps else qps[-1]
    ours = next(r for r in results if r["algo"] == "hqp-nullspace" and r["dof"] == big and r["qp"] == shipped)
    report["goal"] = {
        "algo": "hqp-nullspace",
        "dof": big,
        "qp": ours["qp"],
        "p50_ms": ours["tick_ms"]["p50"],
        "p99_ms": ours["tick_ms"]["p99"],
        "cpu_p50_ms": ours["tick_cpu_ms"]["p50"],
        "cpu_p99_ms": ours["tick_cpu_ms"]["p99"],
        "p50_goal_ms": 0.15,
        "p99_goal_ms": 0.4,
        "met": ours["tick_ms"]["p50"] <= 0.15 and ours["tick_ms"]["p99"] <= 0.4,
    }
    if mink_solver:
        try:
            mk = time_mink(robots[big], frames_by_dof[big], rate, warmup, mink_solver)
        except ImportError as exc:
            mk = {"error": f"mink not available: {exc}"}
        else:
            mk["ratio_p50_vs_hqp_nullspace"] = round(mk["tick_ms"]["p50"] / ours["tick_ms"]["p50"], 2)
        report["mink"] = mk
    return report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``mimic bench solvers``."""
    parser.add_argument("--json", type=Path, default=None, help="write the report here")
    parser.add_argument("--targets", type=Path, default=None, help=".npz of recorded targets (see module doc)")
    parser.add_argument(
        "--clip", type=Path, action="append", default=None, help="real BVH/C3D clip, retargeted (repeatable)"
    )
    parser.add_argument("--seconds", type=float, default=6.0, help="length of the synthetic trajectory [s]")
    parser.add_argument("--rate", type=float, default=500.0, help="solver rate [Hz]")
    parser.add_argument("--algos", nargs="+", default=list(ALGORITHMS), choices=sorted(ALGORITHMS))
    parser.add_argument("--qps", nargs="+", default=["piqp", "daqp"], choices=["piqp", "daqp"])
    parser.add_argument("--dofs", nargs="+", type=int, default=[14, 17], choices=[14, 17])
    parser.add_argument("--warmup", type=int, default=200, help="ticks left out of the statistics")
    parser.add_argument("--mink-solver", default="daqp", help="qpsolvers name for mink ('none' to skip)")
    parser.add_argument("--robot", default=None, help="robot profile")
    add_switches(parser)


def main(args: argparse.Namespace) -> int:
    """Run the benchmark, print a table and the JSON report."""
    robots = {dof: build_robot_model(args.robot, with_waist=dof == 17) for dof in sorted(set(args.dofs))}
    frames_by_dof = {}
    clip_frames = clip_targets(args.clip) if args.clip else None
    for dof, robot in robots.items():
        if args.targets is not None:
            frames_by_dof[dof] = load_targets(args.targets)
        elif clip_frames is not None:
            frames_by_dof[dof] = clip_frames
        else:
            # Each model's own motion, so that every target is reachable by that model.
            frames_by_dof[dof] = synthetic_targets(robot, args.seconds)
    mink_solver = None if args.mink_solver == "none" else args.mink_solver
    switches = switch_values(args)
    report = run_bench(frames_by_dof, robots, args.algos, args.qps, args.rate, args.warmup, mink_solver, switches)
    if args.targets:
        report["targets"] = str(args.targets)
    elif args.clip:
        report["targets"] = "retargeted clips: " + ", ".join(p.name for p in args.clip)
    else:
        report["targets"] = f"synthetic FK trajectory, {args.seconds} s at 100 Hz"
    lines = ["algo            qp     dof   p50 [ms]  p99 [ms]  cpu p50   cpu p99  paper [ms]"]
    for r in report["results"]:
        paper = PAPER_MS.get(r["algo"])
        w, c = r["tick_ms"], r["tick_cpu_ms"]
        lines.append(
            f"{r['algo']:<15} {r['qp']:<6} {r['dof']:>3}  {w['p50']:>8.4f}  {w['p99']:>8.4f}  {c['p50']:>8.4f}"
            f"  {c['p99']:>8.4f}  {paper if paper else '-':>10}"
        )
    if "mink" in report and "tick_ms" in report["mink"]:
        mk = report["mink"]
        lines.append(
            f"{'mink solve_ik':<15} {mk['solver']:<6} {mk['dof']:>3}  {mk['tick_ms']['p50']:>8.4f}"
            f"  {mk['tick_ms']['p99']:>8.4f}           -   ({mk['ratio_p50_vs_hqp_nullspace']}x hqp-nullspace p50)"
        )
    log.info("\n%s", "\n".join(lines))
    emit_json(report, args.json)
    return 0


if __name__ == "__main__":
    import sys

    from shared.bus import setup_logging

    setup_logging("INFO")
    p = argparse.ArgumentParser(prog="python -m services.solver.bench")
    add_arguments(p)
    sys.exit(main(p.parse_args()))
