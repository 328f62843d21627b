"""Bus wiring of ``wbqp-accel`` for wheeled-legged arm robots: ``mimic solve --robot models/tita_piper.toml``.

Subscribes (latest only) to ``keys.targets`` (TaskTargets; ``right_wrist`` drives the gripper) and
publishes the 7-D JointCommand of :class:`~services.solver.wbqp_core.WbqpCore` on
``keys.command(<id>)`` at ``--rate`` Hz on monotonic deadlines. The planner runs on its own
prediction (see ``services/wbc/README.md`` for why not on the measured robot).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from services.solver.wbqp_accel import WbqpConfig
from services.solver.wbqp_core import WbqpCore, WbqpCoreConfig
from shared.bus import ServiceRunner
from shared.messages import TaskTargets
from shared.robot.wheeled import build_wheeled_robot

#: Ticks between latency-percentile updates in the status.
STATS_WINDOW = 500


def run(args: argparse.Namespace) -> int:
    """Run the wheeled-robot solver until SIGINT/SIGTERM."""
    robot = build_wheeled_robot(args.robot)
    core = WbqpCore(robot, WbqpCoreConfig(solver_id=args.solver_id, planner=WbqpConfig(dt=1.0 / args.rate, qp=args.qp)))
    period = core.dt
    with ServiceRunner("solver", args, instance=args.solver_id) as svc:
        targets = svc.subscribe_latest(svc.keys.targets, TaskTargets.decode, stream="targets")
        pub = svc.publisher(svc.keys.command(args.solver_id))
        svc.status.state = "holding"
        svc.log.info("%s/wbqp-accel with %s on %s, %.0f Hz", args.solver_id, args.qp, robot.profile.name, args.rate)
        ticks_ms: list[float] = []
        next_t = time.monotonic()
        while not svc.stop_event.is_set():
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            t = time.monotonic()
            cmd = core.step(targets.take(), t)
            svc.publish(pub, cmd, stream="commands")
            svc.status.state = {"init": "holding", "held": "holding", "failed": "degraded"}.get(cmd.status, "ok")
            svc.status.outcome(cmd.status)
            ticks_ms.append(cmd.solve_ms)
            if len(ticks_ms) >= STATS_WINDOW:
                arr = np.asarray(ticks_ms)
                svc.status.extra.update(
                    {"tick_ms_p50": float(np.percentile(arr, 50)), "tick_ms_p99": float(np.percentile(arr, 99))}
                )
                ticks_ms.clear()
            next_t += period
            if t - next_t > 5 * period:
                next_t = t + period  # far behind (machine stalled): skip the missed ticks
    return 0
