"""`mimic solve --robot models/tita_piper.toml` on a real Zenoh bus: TaskTargets in, 7-D JointCommands out."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import zenoh

from services.launcher.supervisor import stop_processes
from services.router.cli import router_config
from services.solver.wbqp_accel import Q_NAMES
from shared.bus import bus_args, zenoh_config
from shared.keys import Keys
from shared.messages import Header, JointCommand, RobotState, Target, TaskTargets
from shared.robot.wheeled import build_wheeled_robot

pytestmark = [pytest.mark.integration, pytest.mark.slow]


@pytest.fixture()
def router(zenoh_endpoint):
    session = zenoh.open(router_config([zenoh_endpoint], None))
    yield zenoh_endpoint
    session.close()


def test_wheeled_solver_rolls_the_torso_towards_a_far_hand_target(router):
    robot = build_wheeled_robot("tita_piper")
    session = "wbqp_it"
    keys = Keys(session)
    client = zenoh.open(zenoh_config(bus_args(connect=[router])))
    got: queue.Queue = queue.Queue()
    client.declare_subscriber(keys.command("main"), lambda s: got.put(JointCommand.decode(s.payload.to_bytes())))
    pub = client.declare_publisher(keys.targets)
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    cmd = [
        sys.executable,
        "-m",
        "services.cli",
        "solve",
        "--robot",
        "models/tita_piper.toml",
        "--connect",
        router,
        "--session",
        session,
        "--rate",
        "200",
    ]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = got.get(timeout=120)  # the process is up and holding before any target
        assert first.status == "init" and first.joints == list(Q_NAMES) and first.algo == "wbqp-accel"
        p0 = robot.kin.hand(np.r_[robot.profile.start_base, robot.profile.start_arm])
        goal = p0 + np.array([0.4, 0.0, 0.0])  # beyond the arm's own reach forward
        last = None
        # Under load the solver ticks slower than --rate and its plan (integrated per tick) lags the
        # wall clock: keep the goal up until the hand is there, for at most 30 s.
        t_end = time.monotonic() + 30.0
        seq = 0
        while time.monotonic() < t_end:
            seq += 1
            s = min(seq / 150.0, 1.0)  # a 3 s ramp at 50 Hz, then held
            tg = Target(p0 + s * (goal - p0), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3))
            pub.put(TaskTargets(Header(seq, seq / 50.0, time.time_ns()), {"right_wrist": tg}).encode())
            time.sleep(0.02)
            while not got.empty():
                last = got.get_nowait()
            if s >= 1.0 and last is not None and np.linalg.norm(robot.kin.hand(last.q) - goal) < 0.02:
                break
        assert last is not None and last.status in ("ok", "infeasible"), last and last.reason
        assert last.q[0] > 0.05  # the torso rolled forward
        assert np.linalg.norm(robot.kin.hand(last.q) - goal) < 0.02
    finally:
        code = stop_processes(proc, sig=signal.SIGTERM)[0]
        client.close()
    assert code == 0, proc.stderr.read()


def test_wheeled_solver_and_sim_on_the_bus(router):
    """`mimic solve` and `mimic sim` with --robot models/tita_piper.toml: the simulated torso rolls and balances."""
    robot = build_wheeled_robot("tita_piper")
    session = "wbqp_sim_it"
    keys = Keys(session)
    client = zenoh.open(zenoh_config(bus_args(connect=[router])))
    states: queue.Queue = queue.Queue()
    client.declare_subscriber(keys.sim_state, lambda s: states.put(RobotState.decode(s.payload.to_bytes())))
    pub = client.declare_publisher(keys.targets)
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    base = [sys.executable, "-m", "services.cli"]
    bus = ["--robot", "models/tita_piper.toml", "--connect", router, "--session", session]
    procs = [
        subprocess.Popen([*base, "sim", *bus], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
        subprocess.Popen(
            [*base, "solve", *bus, "--rate", "200"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        ),
    ]
    try:
        first = states.get(timeout=120)
        assert first.joints == list(Q_NAMES) and "right_wrist" in first.frames
        p0 = robot.kin.hand(np.r_[robot.profile.start_base, robot.profile.start_arm])
        goal = p0 + np.array([0.3, 0.0, 0.0])
        last = None
        t_end = time.monotonic() + 10.0
        seq = 0
        while time.monotonic() < t_end:
            seq += 1
            s = min(seq / 200.0, 1.0)  # a 4 s ramp at 50 Hz, then held
            tg = Target(p0 + s * (goal - p0), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3))
            pub.put(TaskTargets(Header(seq, seq / 50.0, time.time_ns()), {"right_wrist": tg}).encode())
            time.sleep(0.02)
            while not states.empty():
                last = states.get_nowait()
        assert last is not None and not last.holding
        assert last.q[0] > 0.02  # the simulated torso rolled forward
        assert last.q[2] > 0.3  # and stands
    finally:
        codes = stop_processes(*procs, sig=signal.SIGTERM)
        client.close()
    assert codes == [0, 0], [p.stderr.read()[-2000:] for p in procs]
