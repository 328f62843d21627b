"""Bus wiring of the sim service: JointCommands in, RobotState out.

* Subscribes ``keys.all_commands`` and keeps the commands published on the followed
  solver's key (others are ignored, counted in ``extra.ignored``, and never decoded).
  Real time keeps only the newest command (overwritten ones count as dropped) and
  applies it as soon as it arrives (the loop waits on the mailbox, not in a sleep);
  lock-step queues up to :data:`LOCKSTEP_QUEUE` (beyond: the oldest dropped, counted).
* Publishes :class:`RobotState` on ``keys.sim_state``: at ``--state-rate`` of
  simulated time in real time, and with ``--state-on-command`` also right after each
  applied command (its header, so latency "frame -> command applied" is observable);
  after every command in lock-step.
* Serves ``keys.sim_follow``: without payload it returns ``{"follow": id}`` (msgpack);
  a payload (msgpack string, msgpack/JSON map ``{"follow": id}`` or plain UTF-8 text)
  switches to that solver id and returns the new value.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import msgpack

from services.sim.render import BackgroundFrameWriter, FrameWriter, open_renderer
from services.sim.resume import save_state
from services.sim.sim_core import SimCore
from shared.bus import ServiceRunner
from shared.keys import Keys
from shared.messages import JointCommand, MessageError, parse_query

#: Longest wall-clock backlog the real-time clock catches up on before it skips [s].
MAX_CATCHUP = 0.05
#: Longest the real-time loop sleeps while the watchdog holds and no state or status is due [s]: the
#: physics it then steps in one batch stays well inside MAX_CATCHUP.
MAX_IDLE_WAIT = 0.01
#: How often the joint positions are written for a restart [s].
STATE_SAVE_PERIOD = 0.25
#: Shortest interval between two "velocity past its limit" warnings [s].
VELOCITY_LOG_PERIOD = 5.0
#: Commands queued for the lock-step clock before the oldest is dropped.
LOCKSTEP_QUEUE = 10000
#: ``--state-on-command``: after a state published on a command, the next periodic one is due this
#: many state periods later. Commands at the state rate then publish one state each instead of
#: racing the periodic clock on their jitter (a periodic state, then the command's a moment later).
STATE_IDLE_PERIODS = 1.5


def parse_follow(payload: bytes) -> str:
    """Solver id from a follow-queryable payload (msgpack str/map, JSON map or text).

    Raises:
        ValueError: empty or not a single key chunk ``[A-Za-z0-9_-]+``.
    """
    try:
        value = parse_query(payload)
    except MessageError as exc:
        raise ValueError(exc.detail) from None
    if isinstance(value, dict):
        value = value.get("follow")
    if not isinstance(value, str) or not value:
        raise ValueError("follow payload must name a solver id (text, msgpack string or {'follow': id})")
    Keys().command(value)  # raises ValueError unless it is one key chunk
    return value


class SimNode:
    """Glue between a :class:`SimCore` and a :class:`ServiceRunner`.

    Args:
        core: the simulation.
        svc: an entered ServiceRunner.
        lockstep: queue every command and advance ``lockstep_dt`` per command.
        lockstep_dt: simulated time per command in lock-step [s].
        state_rate: RobotState rate in real time [Hz of simulated time].
        renderer: optional frame writer.
        state_on_command: real time: also publish a RobotState right after each applied command.
    """

    def __init__(
        self,
        core: SimCore,
        svc: ServiceRunner,
        lockstep: bool = False,
        lockstep_dt: float = 0.01,
        state_rate: float = 200.0,
        renderer: FrameWriter | BackgroundFrameWriter | None = None,
        state_on_command: bool = False,
    ):
        self.core = core
        self.svc = svc
        self.lockstep = lockstep
        self.lockstep_dt = lockstep_dt
        self.state_period = 1.0 / state_rate
        self.renderer = renderer
        self.state_on_command = state_on_command
        self._follow_lock = threading.Lock()
        self.follow = core.solver_id
        self._follow_key = svc.keys.command(self.follow)
        self.ignored = 0
        self.overruns = 0
        self.state_file: Path | None = None  # where keep_state writes (None: off)
        self._next_save = 0.0
        self._velocity_excess_said = 0  # velocity_excess_steps at the last warning
        self._velocity_said_at = -float("inf")  # monotonic time of that warning [s]
        self._rejects_seen: dict[str, int] = {}
        self._pub = svc.publisher(svc.keys.sim_state)
        self.commands = svc.subscribe_latest(
            svc.keys.all_commands,
            JointCommand.decode,
            stream="commands",
            depth=LOCKSTEP_QUEUE if lockstep else 1,
            accept=self._followed,
        )
        svc.queryable(svc.keys.sim_follow, self.on_follow)

    # ------------------------------------------------------------------ callbacks (zenoh threads)

    def _followed(self, key: str) -> bool:
        """Sample filter: only the followed solver's key (no decoding in the Zenoh thread)."""
        if key == self._follow_key:
            return True
        self.ignored += 1
        return False

    def on_follow(self, payload: bytes | None) -> bytes:
        """Queryable handler: GET the followed solver id; a payload sets it."""
        if payload:
            new = parse_follow(payload)
            with self._follow_lock:
                if new != self.follow:
                    self.svc.log.info("following solver %r (was %r)", new, self.follow)
                self.follow = new
                self._follow_key = self.svc.keys.command(new)
        return msgpack.packb({"follow": self.follow})

    # ------------------------------------------------------------------ main loop

    def _apply(self, cmd: JointCommand | None) -> bool:
        """Apply a command of the followed solver; True if the sim took it."""
        if cmd is None:
            return False
        if cmd.solver_id != self.follow:  # queued before a follow switch, or a key/id mismatch
            self.ignored += 1
            return False
        self.core.solver_id = self.follow
        if self.core.apply(cmd):
            return True
        c = self.core.counters
        for reason, n in c.rejects.items():
            if n > self._rejects_seen.get(reason, 0):
                self.svc.status.reject(reason, c.last_reject)
                self._rejects_seen[reason] = n
        return False

    def _publish(self) -> None:
        self.core.solver_id = self.follow
        self.svc.publish(self._pub, self.core.state(), stream="state")

    def _render(self) -> None:
        if self.renderer is not None:
            self.renderer.maybe_render(self.core.robot.data)

    def keep_state(self, now: float, force: bool = False) -> None:
        """Write the joint positions to the state file every STATE_SAVE_PERIOD (see :mod:`.resume`)."""
        if self.state_file is None or (not force and now < self._next_save):
            return
        self._next_save = now + STATE_SAVE_PERIOD
        try:
            save_state(self.state_file, list(self.core.joint_names), self.core.q)
        except OSError as exc:
            self.svc.status.error(f"cannot write the sim state file {self.state_file}: {exc}")
            self.state_file = None

    def update_status(self) -> None:
        """Refresh the status state and service-specific figures."""
        st = self.svc.status
        c = self.core.counters
        st.state = "holding" if self.core.holding else "ok"
        st.extra.update(
            {
                "applied": float(c.applied),
                "clipped": float(c.clipped),
                "holds": float(c.holds),
                "ignored": float(self.ignored),
                "overruns": float(self.overruns),
                "sim_time": self.core.time,
                "max_contacts": float(self.core.max_contacts),
            }
        )
        excess = getattr(c, "velocity_excess_steps", None)  # the wheeled core (seed 002) does not count it
        if excess is None:
            return
        st.extra["velocity_excess_steps"] = float(excess)
        st.extra["worst_velocity_ratio"] = c.worst_velocity_ratio
        if excess > self._velocity_excess_said:
            # The robot, not a command, went past a limit: say it (status + log), at most every 5 s.
            now = time.monotonic()
            if now - self._velocity_said_at >= VELOCITY_LOG_PERIOD:
                j = self.core.joint_names.index(c.worst_velocity_joint)
                msg = (
                    f"simulated joint velocity past its limit in {c.velocity_excess_steps} physics step(s) so far; "
                    f"worst {c.worst_velocity_joint} {c.worst_velocity_ratio * self.core.vmax[j]:.2f} rad/s vs "
                    f"{self.core.vmax[j]:.2f} rad/s (the commands stay within it: servo overshoot)"
                )
                st.error(msg)  # logs it too
                self._velocity_excess_said, self._velocity_said_at = c.velocity_excess_steps, now

    def run_realtime(self, stop: threading.Event, duration: float | None = None) -> None:
        """Pace physics to the wall clock until ``stop`` (or ``duration`` [s] of sim time).

        While commands come, the loop waits on the command mailbox for one physics step at a time,
        so a command is applied (and its state published) with at most a step to catch up first.
        While the watchdog holds (no command for ``watchdog`` s, or none yet) nothing is in a hurry:
        the loop sleeps until the next periodic state or status, or a command, at most
        MAX_IDLE_WAIT, and then steps the physics in one batch (the same 1 ms steps, each with its
        servo update and checks). Waking for every step cost ~0.2 core with no command at all.
        """
        core = self.core
        dt = core.dt
        self._wall0 = time.monotonic()
        self._sim0 = core.time
        self._next_pub = core.time
        next_status = self._wall0
        while not stop.is_set():
            self._catch_up(dt)
            now = time.monotonic()
            if now >= next_status:
                self.update_status()
                next_status = now + 0.1
                self.keep_state(now)
            if duration is not None and core.time - self._sim0 >= duration:
                break
            # Wait on the mailbox, not in a sleep: a command is applied (and, with state_on_command,
            # its state published) as soon as it arrives.
            if core.holding:
                state_due = self._wall0 + (self._next_pub - self._sim0) + 0.1 * dt
                wait = min(state_due, next_status, now + MAX_IDLE_WAIT) - now
            else:  # until the next physics step is due
                wait = dt - ((now - self._wall0) - (core.time - self._sim0))
            cmd = self.commands.take(timeout=wait if wait > 0 else None)
            if cmd is None:
                continue
            self._catch_up(dt)  # the command applies at the simulated time it arrived (within a step)
            if self._apply(cmd) and self.state_on_command:
                self._publish()
                self._next_pub = core.time + STATE_IDLE_PERIODS * self.state_period

    def _catch_up(self, dt: float) -> None:
        """Step the physics up to the wall clock, publishing the periodic states that fall due."""
        core = self.core
        behind = (time.monotonic() - self._wall0) - (core.time - self._sim0)
        if behind > MAX_CATCHUP:
            # Too far behind (slow machine, rendering): drop the backlog rather than spiral.
            self.overruns += 1
            self._wall0 += behind - dt
            behind = dt
        for _ in range(int(behind / dt)):
            core.step_physics(1)
            if core.time + 1e-9 >= self._next_pub:
                self._publish()
                self._next_pub += self.state_period
                if self._next_pub < core.time:
                    self._next_pub = core.time + self.state_period
            self._render()

    def run_lockstep(self, stop: threading.Event) -> None:
        """Advance ``lockstep_dt`` per command, as fast as commands come, until ``stop``."""
        while not stop.is_set():
            cmd = self.commands.take(timeout=0.1)
            if cmd is None:
                self.update_status()
                continue
            self._apply(cmd)
            steps = max(1, round(self.lockstep_dt / self.core.dt))
            for _ in range(steps):
                self.core.step_physics(1)
                self._render()
            self._publish()
            self.update_status()


def run(args, core: SimCore) -> int:
    """Run the sim service until SIGINT/SIGTERM."""
    renderer = None
    if args.render:
        renderer, why = open_renderer(core.robot.model, Path(args.render), fps=args.render_fps, fmt=args.render_format)
        if renderer is None:
            import logging

            logging.getLogger("mimic.sim").warning("%s", why)
    try:
        with ServiceRunner("sim", args) as svc:
            node = SimNode(
                core,
                svc,
                lockstep=args.clock == "lockstep",
                lockstep_dt=args.lockstep_dt,
                state_rate=args.state_rate,
                renderer=renderer,
                state_on_command=args.state_on_command,
            )
            svc.log.info(
                "sim %s clock, following %s on %s, state on %s, servo %s",
                args.clock,
                node.follow,
                svc.keys.all_commands,
                svc.keys.sim_state,
                core.info(),
            )
            state_file = getattr(args, "state_file", "none")
            # Only a core that can resume (fixed-base joint state) keeps a state file: a wheeled robot's
            # floating torso cannot be put back from joint positions.
            resumable = hasattr(core, "resume")
            node.state_file = None if state_file in (None, "none") or not resumable else Path(state_file)
            if node.lockstep:
                node.run_lockstep(svc.stop_event)
            else:
                node.run_realtime(svc.stop_event)
            node.update_status()
            node.keep_state(time.monotonic(), force=True)
    finally:
        if renderer is not None:
            renderer.close()
    return 0
