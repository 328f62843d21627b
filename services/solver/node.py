"""Bus wiring of the solver: fixed-rate loop around :class:`SolverCore`.

Subscribes (latest only) to ``keys.targets`` (TaskTargets) and
``keys.sim_state`` (RobotState); publishes JointCommand on
``keys.command(<id>)`` at ``--rate`` Hz on monotonic deadlines, or also on every
target arrival with ``--trigger event``.
"""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np

from services.solver.core import MIN_STEP, SolverConfig, SolverCore
from shared import config as shared_config
from shared.bus import ServiceRunner
from shared.messages import JointCommand, RobotState, TaskTargets
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


#: ``--trigger event``: after a tick on new targets, the next tick without targets is due this many
#: periods later (after one without, one period). A stream at the control rate then ticks once per
#: target instead of racing the clock on its jitter (a tick on the deadline, then one on the target
#: a moment later: twice the solver work, commands and states); below the core's MAX_STEP_TICKS, so
#: a stream that stops still ticks before any motion is lost to the core's step clamp.
EVENT_IDLE_PERIODS = 1.5


class TickClock:
    """When the next tick is due: on a fixed period, or also on every target arrival (``event``).

    A tick that comes late (the machine stalled) does not make up the missed ones: the core
    steps by the real elapsed time anyway, so catching up would only add ticks, not motion.
    """

    def __init__(self, period: float, event: bool):
        self.period = period
        self.event = event
        self.next_t = time.monotonic()
        self.overruns = 0

    def wait(self, targets) -> TaskTargets | None:
        """Sleep until the deadline (event: or until targets arrive); returns the newest targets or None."""
        delay = self.next_t - time.monotonic()
        if self.event:
            return targets.take(timeout=max(delay, MIN_STEP))
        if delay > 0:
            time.sleep(delay)
        return targets.take()

    def ticked(self, t: float, on_targets: bool = False) -> None:
        """Schedule the deadline after a tick at t [s] (monotonic); ``on_targets``: it had new targets."""
        if self.event:
            self.next_t = t + self.period * (EVENT_IDLE_PERIODS if on_targets else 1.0)
            return
        self.next_t += self.period
        if self.next_t < t:
            self.overruns += 1
            self.next_t = t + self.period


class TickStats:
    """Tick-time percentiles and the core's counters, published in the service status every STATS_WINDOW ticks."""

    def __init__(self) -> None:
        self.ticks_ms: list[float] = []

    def add(self, svc, cmd: JointCommand, core: SolverCore, clock: TickClock) -> None:
        svc.status.state = {"init": "holding", "held": "holding", "failed": "degraded"}.get(cmd.status, "ok")
        svc.status.outcome(cmd.status)
        self.ticks_ms.append(cmd.solve_ms)
        if len(self.ticks_ms) < STATS_WINDOW:
            return
        arr = np.asarray(self.ticks_ms)
        svc.status.extra.update(
            {
                "tick_ms_p50": float(np.percentile(arr, 50)),
                "tick_ms_p99": float(np.percentile(arr, 99)),
                "overruns": float(clock.overruns),
                **{k: float(v) for k, v in core.counts.items()},
            }
        )
        self.ticks_ms.clear()


def start_state(core: SolverCore, states, joint_map: JointMap, wait: float, log) -> bool:
    """Start from the robot's measured joints if a state arrives within ``wait`` [s], else from rest.

    Returns:
        True when started from a measured state.
    """
    state = states.take(timeout=wait)
    q0 = joint_map(state) if state is not None else None
    if q0 is not None:
        core.reset(q0)
        log.info("initialised from measured state (sim following %r)", state.solver_id)
        return True
    core.reset(core.robot.q_rest)
    log.info("no robot state within %.2f s: starting from the rest pose", wait)
    return False


def measured_joints(state: RobotState | None, joint_map: JointMap, solver_id: str) -> np.ndarray | None:
    """Measured joints of a state from the sim following this solver (shadows get None)."""
    if state is None or state.solver_id != solver_id:
        return None
    return joint_map(state)


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
    with ServiceRunner("solver", args, instance=args.solver_id) as svc:
        log = svc.log
        targets = svc.subscribe_latest(svc.keys.targets, TaskTargets.decode, stream="targets")
        # Only the newest state matters, and only when a tick starts: the tick drains the ring itself
        # (no receiver thread waking up, and taking the GIL, for every state between ticks).
        states = svc.subscribe_reader(svc.keys.sim_state, RobotState.decode, stream="sim_state")
        pub = svc.publisher(svc.keys.command(args.solver_id))
        svc.status.state = "holding"
        # A solver started mid-stream continues from where the robot is: wait briefly for its state.
        anchored = start_state(core, states, joint_map, args.startup_wait, log)
        log.info(
            "%s/%s with %s, %d joints, %.0f Hz (%s), smoothing %s",
            args.solver_id,
            args.algo,
            args.qp,
            robot.nq,
            args.rate,
            getattr(args, "trigger", "rate"),
            "on" if core.smoother is not None else "off",
        )
        clock = TickClock(core.dt, getattr(args, "trigger", "rate") == "event")
        stats = TickStats()
        while not svc.stop_event.is_set():
            msg = clock.wait(targets)
            t = time.monotonic()
            state = states.take()
            if not anchored and state is not None and (q_first := joint_map(state)) is not None:
                # Started from rest because no state came in time (a loaded machine): re-anchor on the
                # first one, or the first command would jump from the robot's pose to the rest pose.
                core.reset(q_first)
                anchored = True
                log.info("re-initialised from the first robot state (sim following %r)", state.solver_id)
            # The solver integrates its own commands (feeding back the servo lag would add it to every
            # step); the measured joints of the robot following this solver bound how far the command
            # may lead them, and with --closed-loop re-anchor it after a jump. Shadows stay open loop.
            cmd = core.step(msg, measured_joints(state, joint_map, args.solver_id), t)
            svc.publish(pub, cmd, stream="commands")
            stats.add(svc, cmd, core, clock)
            clock.ticked(t, msg is not None)
        # The last status (published on exit) carries the final counts, however few ticks ran.
        svc.status.extra.update({k: float(v) for k, v in core.counts.items()})
    return 0
