"""Bus wiring of the solver: fixed-rate loop around :class:`SolverCore`.

Subscribes (latest only) to ``keys.targets`` (TaskTargets) and
``keys.sim_state`` (RobotState); publishes JointCommand on
``keys.command(<id>)`` at ``--rate`` Hz on monotonic deadlines.
"""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np

from services.solver.core import SolverConfig, SolverCore
from shared import config as shared_config
from shared.bus import ServiceRunner
from shared.messages import RobotState, TaskTargets
from shared.robot.pinocchio_model import build_robot_model

#: Ticks between latency-percentile updates in the status.
STATS_WINDOW = 500


class JointMap:
    """Maps a RobotState's joint list onto the solver's joint order (cached per joint list)."""

    def __init__(self, joint_names: tuple[str, ...]):
        self.joint_names = joint_names
        self._cache: dict[tuple[str, ...], np.ndarray | None] = {}

    def __call__(self, state: RobotState) -> np.ndarray | None:
        """(n,) measured q [rad] in solver order, or None when the state lacks some of our joints."""
        key = tuple(state.joints)
        idx = self._cache.get(key, False)
        if idx is False:
            pos = {n: i for i, n in enumerate(key)}
            idx = None if any(j not in pos for j in self.joint_names) else np.array([pos[j] for j in self.joint_names])
            self._cache[key] = idx
        return None if idx is None else state.q[idx]


def config_from_args(args: argparse.Namespace) -> SolverConfig:
    """SolverConfig from the ``mimic solve`` flags (validated by SolverConfig)."""
    return shared_config.config_from_args(SolverConfig, args)


def run(args: argparse.Namespace) -> int:
    """Run the solver service until SIGINT/SIGTERM."""
    robot = build_robot_model(args.robot, with_waist=not args.no_waist)
    from services.posture.policy import PolicyError

    try:
        core = SolverCore(robot, config_from_args(args))
    except PolicyError as exc:
        logging.getLogger("mimic.solve").error("%s", exc)
        return 2
    joint_map = JointMap(robot.joint_names)
    period = core.dt
    with ServiceRunner("solver", args, instance=args.solver_id) as svc:
        log = svc.log
        targets = svc.subscribe_latest(svc.keys.targets, TaskTargets.decode, stream="targets")
        states = svc.subscribe_latest(svc.keys.sim_state, RobotState.decode, stream="sim_state")
        pub = svc.publisher(svc.keys.command(args.solver_id))
        svc.status.state = "holding"
        # A solver started mid-stream continues from where the robot is: wait briefly for its state.
        state = states.take(timeout=args.startup_wait)
        q0 = joint_map(state) if state is not None else None
        anchored = q0 is not None
        if q0 is not None:
            core.reset(q0)
            log.info("initialised from measured state (sim following %r)", state.solver_id)
        else:
            core.reset(robot.q_rest)
            log.info("no robot state within %.2f s: starting from the rest pose", args.startup_wait)
        log.info(
            "%s/%s with %s, %d joints, %.0f Hz, smoothing %s",
            args.solver_id,
            args.algo,
            args.qp,
            robot.nq,
            args.rate,
            "on" if core.smoother is not None else "off",
        )
        ticks_ms: list[float] = []
        next_t = time.monotonic()
        overruns = 0
        event = getattr(args, "trigger", "rate") == "event"
        while not svc.stop_event.is_set():
            delay = next_t - time.monotonic()
            if event:
                # Wake on new targets or at the deadline, whichever comes first.
                msg = targets.take(timeout=delay if delay > 0 else None)
            else:
                if delay > 0:
                    time.sleep(delay)
                msg = targets.take()
            t = time.monotonic()
            state = states.take()
            if not anchored and state is not None and (q_first := joint_map(state)) is not None:
                # Started from rest because no state came in time (a loaded machine): re-anchor on the
                # first one, or the first command would jump from the robot's pose to the rest pose.
                core.reset(q_first)
                anchored = True
                log.info("re-initialised from the first robot state (sim following %r)", state.solver_id)
            q_meas = None
            # The solver integrates its own commands (feeding back the servo lag would add it to every
            # step, and re-anchoring on it makes the command jump). Measured joints re-anchor only with
            # --closed-loop, and only while the robot follows this solver (shadows stay open loop).
            if args.closed_loop and state is not None and state.solver_id == args.solver_id:
                q_meas = joint_map(state)
            cmd = core.step(msg, q_meas, t)
            svc.publish(pub, cmd, stream="commands")
            ticks_ms.append(cmd.solve_ms)
            svc.status.state = {"init": "holding", "held": "holding", "failed": "degraded"}.get(cmd.status, "ok")
            svc.status.outcome(cmd.status)
            if len(ticks_ms) >= STATS_WINDOW:
                arr = np.asarray(ticks_ms)
                svc.status.extra.update(
                    {
                        "tick_ms_p50": float(np.percentile(arr, 50)),
                        "tick_ms_p99": float(np.percentile(arr, 99)),
                        "overruns": float(overruns),
                        **{k: float(v) for k, v in core.counts.items()},
                    }
                )
                ticks_ms.clear()
            next_t = t + period if event else next_t + period
            if t - next_t > 5 * period:
                # Far behind (machine stalled): skip the missed ticks instead of bursting.
                overruns += 1
                next_t = t + period
        # The last status (published on exit) carries the final counts, however few ticks ran.
        svc.status.extra.update({k: float(v) for k, v in core.counts.items()})
    return 0
