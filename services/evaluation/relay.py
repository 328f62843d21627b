"""No-work stand-ins for retarget, solver and sim: the bus floor of ``mimic bench pipeline``.

``mimic bench pipeline --noop`` starts these instead of the real services, as separate
processes on the same router, session and keys. Each one receives the real message, decodes it
as its service does (the full schema check), and publishes the real downstream message type
(precomputed, sized like the service's: 4 task targets with upper arms, 17 joints, 4 frame
poses) carrying the input's header, so the bench reads the same stamps. What is left is what
three Python processes on Zenoh cost per frame whatever the services compute: the floor under
the pipeline goals.

``--delivery`` chooses how a sample reaches the stage's worker:

* ``shipped``: the services' own wiring (``shared.bus``): the retarget worker blocking on its
  Zenoh ring (:meth:`~shared.bus.ServiceRunner.subscribe_reader`), the solver's targets and the
  sim's commands through a ring drained by a receiver thread into a newest-wins mailbox
  (:meth:`~shared.bus.ServiceRunner.subscribe_latest`), the solver's ``--trigger event`` clock
  (:class:`~services.solver.node.TickClock`, idle ticks included) and robot states read at its
  tick, the sim's periodic states while no command comes;
* ``ring``: every stage's worker blocks in its own ring's ``recv()`` (no receiver thread; no
  idle ticks or periodic states either: ``recv()`` has no timeout in zenoh-python 1.10);
* ``inline``: decode and publish in Zenoh's callback itself, no thread hand-off at all (the
  lower bound of any delivery).

``--depth N`` (shipped delivery) keeps N messages in the solver's targets and the sim's commands
mailboxes instead of the services' newest-wins 1: what a deeper queue would do to the drops.

Run by the bench as ``python -m services.evaluation.relay STAGE [--delivery D] [--rate HZ]``
with the bus flags of every service (``MIMIC_SESSION``, ``MIMIC_CONNECT``).
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Callable

import numpy as np

# The services' own limits and clocks (imported before the bus is joined, as the services do: the
# seconds of start-up never fall into what the bench measures).
from services.retarget.node import FRAME_MAX_AGE, FRAME_QUEUE, FRAME_RING
from services.sim.node import STATE_IDLE_PERIODS
from services.solver.node import TickClock
from shared.bus import RingReader, ServiceRunner, add_bus_args, setup_logging
from shared.messages import Header, HumanFrame, JointCommand, Pose, RobotState, Target, TaskTargets
from shared.robot.profile import DEFAULT_PROFILE, load_profile
from shared.targets import SIDES, TARGET_NAMES

STAGES = ("retarget", "solver", "sim")
DELIVERIES = ("shipped", "ring", "inline")


# --------------------------------------------------------------------------- the precomputed outputs


def targets_message() -> TaskTargets:
    """A TaskTargets shaped like the retarget's: every target with rotation, both upper arms."""
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    targets = {
        n: Target(np.full(3, 0.1 * (i + 1)), ident, np.zeros(3), np.zeros(3)) for i, n in enumerate(TARGET_NAMES)
    }
    return TaskTargets(Header(0, 0.0, 0), targets, upper_arms={s: ident.copy() for s in SIDES})


def command_message(joints: list[str]) -> JointCommand:
    """A JointCommand shaped like the solver's for ``joints`` (two priority levels' residuals)."""
    n = len(joints)
    return JointCommand(
        Header(0, 0.0, 0), "main", "noop", joints, np.linspace(-0.5, 0.5, n), np.zeros(n), [1e-4, 2e-3], 0.1
    )


def state_message(joints: list[str]) -> RobotState:
    """A RobotState shaped like the sim's for ``joints``, with a pose per task target."""
    n = len(joints)
    frames = {t: Pose(np.full(3, 0.2), np.array([1.0, 0.0, 0.0, 0.0])) for t in TARGET_NAMES}
    return RobotState(Header(0, 0.0, 0), joints, np.linspace(-0.5, 0.5, n), np.zeros(n), frames, 0.0)


# --------------------------------------------------------------------------- stages


class Relay:
    """One stage: its input decoded into ``on_input``, the precomputed output republished with its header.

    Args:
        svc: an entered ServiceRunner named after the stage (its status carries the drops and gaps).
        out_key: the stage's output key. out: the precomputed output message (its ``hdr`` is replaced).
        stream: the output's stream name in the status (as the real service counts it).
    """

    def __init__(self, svc: ServiceRunner, out_key: str, out: TaskTargets | JointCommand | RobotState, stream: str):
        self.svc = svc
        self.out = out
        self.stream = stream
        self.pub = svc.publisher(out_key)

    def emit(self, hdr: Header) -> None:
        """Publish the output with ``hdr`` (encoding included: the services pay it too)."""
        self.out.hdr = hdr
        self.svc.publish(self.pub, self.out, stream=self.stream)


def _loop(svc: ServiceRunner, body: Callable[[], None], name: str) -> None:
    """Run ``body`` in a worker thread until the service stops (a daemon, like the services' workers)."""

    def spin() -> None:
        while not svc.stop_event.is_set():
            body()

    threading.Thread(target=spin, name=name, daemon=True).start()


def _relay_ring(
    svc: ServiceRunner, reader: RingReader, relay: Relay, name: str, also: Callable[[], object] | None = None
) -> None:
    """A worker blocking in ``reader``'s ring: each message taken is relayed with its header
    (``also`` runs first, e.g. the solver's read of the newest robot state)."""

    def step() -> None:
        msg = reader.wait_take()
        if also is not None:
            also()
        if msg is not None:
            relay.emit(msg.hdr)
        elif reader.closed:
            svc.stop_event.wait(0.1)

    _loop(svc, step, name)


def run_retarget(svc: ServiceRunner, delivery: str) -> None:
    """HumanFrames in, TaskTargets out (the retarget's subscription and queue limits)."""
    relay = Relay(svc, svc.keys.targets, targets_message(), "targets")
    if delivery == "inline":
        svc.subscribe(svc.keys.mocap_frame, lambda f: relay.emit(f.hdr), HumanFrame.decode, "frames")
        return
    # shipped and ring alike: the retarget already blocks on its ring.
    frames = svc.subscribe_reader(
        svc.keys.mocap_frame, HumanFrame.decode, "frames", depth=FRAME_QUEUE, max_age=FRAME_MAX_AGE, ring=FRAME_RING
    )
    _relay_ring(svc, frames, relay, "relay-retarget")


def run_solver(svc: ServiceRunner, delivery: str, rate: float, joints: list[str], depth: int = 1) -> None:
    """TaskTargets (and RobotStates) in, JointCommands out on the ``main`` solver's key."""
    relay = Relay(svc, svc.keys.command("main"), command_message(joints), "commands")
    states = svc.subscribe_reader(svc.keys.sim_state, RobotState.decode, "sim_state")
    if delivery == "inline":

        def on_targets(msg: TaskTargets) -> None:
            states.take()
            relay.emit(msg.hdr)

        svc.subscribe(svc.keys.targets, on_targets, TaskTargets.decode, "targets")
        return
    if delivery == "ring":
        targets = svc.subscribe_reader(svc.keys.targets, TaskTargets.decode, "targets")
        _relay_ring(svc, targets, relay, "relay-solver", also=states.take)
        return
    latest = svc.subscribe_latest(svc.keys.targets, TaskTargets.decode, "targets", depth=depth)
    clock = TickClock(1.0 / rate, event=True)
    last = [Header(0, 0.0, 0)]

    def tick() -> None:
        # As the solver node: wait for targets or the idle deadline, read the newest state, publish
        # a command on every tick (an idle tick carries the last targets' header, as the core does).
        msg = clock.wait(latest)
        t = time.monotonic()
        states.take()
        if msg is not None:
            last[0] = msg.hdr
        relay.emit(last[0])
        clock.ticked(t, msg is not None)

    _loop(svc, tick, "relay-solver")


def run_sim(svc: ServiceRunner, delivery: str, state_rate: float, joints: list[str], depth: int = 1) -> None:
    """JointCommands of the followed ``main`` solver in, RobotStates out (one per command)."""
    relay = Relay(svc, svc.keys.sim_state, state_message(joints), "state")
    follow = svc.keys.command("main")
    if delivery == "inline":
        svc.subscribe(follow, lambda c: relay.emit(c.hdr), JointCommand.decode, "commands")
        return
    if delivery == "ring":
        _relay_ring(svc, svc.subscribe_reader(follow, JointCommand.decode, "commands"), relay, "relay-sim")
        return
    # The sim's own subscription: all solvers' commands, only the followed key kept.
    latest = svc.subscribe_latest(
        svc.keys.all_commands, JointCommand.decode, "commands", depth=depth, accept=follow.__eq__
    )
    period = 1.0 / state_rate
    due = [time.monotonic() + period]

    def step() -> None:
        # As the sim with --state-on-command: a state right after each command; while none comes,
        # periodic states (STATE_IDLE_PERIODS after the last command's, then every period).
        cmd = latest.take(timeout=max(due[0] - time.monotonic(), 1e-4))
        now = time.monotonic()
        if cmd is not None:
            relay.emit(cmd.hdr)
            due[0] = now + STATE_IDLE_PERIODS * period
        elif now >= due[0]:
            relay.emit(relay.out.hdr)
            due[0] = now + period

    _loop(svc, step, "relay-sim")


# --------------------------------------------------------------------------- command line


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("stage", choices=STAGES)
    p.add_argument("--delivery", choices=DELIVERIES, default="shipped", help="how a sample reaches the worker")
    p.add_argument("--rate", type=float, default=500.0, help="solver: the event clock's period 1/rate [Hz]")
    p.add_argument("--state-rate", type=float, default=200.0, help="sim: periodic states while idle [Hz]")
    p.add_argument("--robot", default=DEFAULT_PROFILE, help="robot profile: the joints of the messages")
    p.add_argument(
        "--depth",
        type=int,
        default=1,
        help="shipped delivery: messages the solver's targets and the sim's commands mailboxes keep (services: 1)",
    )
    add_bus_args(p)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m services.evaluation.relay", description=__doc__.split("\n")[0])
    add_arguments(p)
    args = p.parse_args(argv)
    setup_logging(prefix=f"relay-{args.stage} ")
    joints = list(load_profile(args.robot).controlled_joints(True))
    with ServiceRunner(args.stage, args, instance="main") as svc:
        if args.stage == "retarget":
            run_retarget(svc, args.delivery)
        elif args.stage == "solver":
            run_solver(svc, args.delivery, args.rate, joints, args.depth)
        else:
            run_sim(svc, args.delivery, args.state_rate, joints, args.depth)
        svc.log.info("relay %s (%s delivery) up", args.stage, args.delivery)
        svc.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
