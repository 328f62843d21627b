"""`mimic solve` processes on a real Zenoh bus over loopback: main + shadow, mid-stream start without a jump."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import time

import numpy as np
import pinocchio as pin
import pytest
import zenoh

from services.launcher.supervisor import stop_processes
from services.router.cli import router_config
from shared.bus import bus_args, zenoh_config
from shared.keys import Keys
from shared.messages import Header, JointCommand, Pose, RobotState, Target, TaskTargets
from shared.robot.pinocchio_model import build_robot_model

pytestmark = [pytest.mark.integration, pytest.mark.slow]


@pytest.fixture()
def router(zenoh_endpoint):
    session = zenoh.open(router_config([zenoh_endpoint], None))
    yield zenoh_endpoint
    session.close()


def _quat(R):
    q = pin.Quaternion(R)
    return np.array([q.w, q.x, q.y, q.z])


def _start(router, session, *extra):
    env = dict(os.environ, PYTHONPATH=os.getcwd())
    cmd = [sys.executable, "-m", "services.cli", "solve", "--connect", router, "--session", session, *extra]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _stop(proc):
    return stop_processes(proc, sig=signal.SIGTERM)[0]


def test_main_and_shadow_solvers_start_from_the_robot_state_and_publish(router):
    robot = build_robot_model()
    session = "solver_it"
    keys = Keys(session)
    client = zenoh.open(zenoh_config(bus_args(connect=[router])))
    got: dict[str, queue.Queue] = {"main": queue.Queue(), "shadow": queue.Queue()}
    for sid, q in got.items():
        client.declare_subscriber(keys.command(sid), lambda s, q=q: q.put(JointCommand.decode(s.payload.to_bytes())))
    state_pub = client.declare_publisher(keys.sim_state)
    target_pub = client.declare_publisher(keys.targets)
    rng = np.random.default_rng(8)
    q_robot = robot.random_configurations(1, rng)[0]  # mid-stream: the robot is far from rest
    poses = robot.frame_poses(q_robot)
    frames = {
        n: Pose(p, _quat(R))
        for n, (p, R) in poses.items()
        if n in ("left_wrist", "right_wrist", "left_elbow", "right_elbow")
    }

    followed = {"q": q_robot}

    def publish_state():
        # A perfect sim following "main": its state is main's latest command.
        q = followed["q"]
        state_pub.put(
            RobotState(Header(0, 0.0), list(robot.joint_names), q, np.zeros(robot.nq), frames, 1.0, "main").encode()
        )

    procs = [
        _start(router, session, "--id", "main", "--algo", "hqp-nullspace", "--qp", "daqp", "--startup-wait", "20"),
        _start(router, session, "--id", "shadow", "--algo", "wqp", "--qp", "piqp", "--startup-wait", "20"),
    ]
    try:
        deadline = time.monotonic() + 40
        first: dict[str, JointCommand] = {}
        while len(first) < 2 and time.monotonic() < deadline:
            publish_state()
            for sid, q in got.items():
                if sid not in first and not q.empty():
                    first[sid] = q.get()
            for p in procs:
                assert p.poll() is None, p.stderr.read()
            time.sleep(0.02)
        assert set(first) == {"main", "shadow"}, "solvers did not publish"
        for sid, cmd in first.items():
            assert cmd.solver_id == sid and cmd.status == "init"
            # Started from the measured state: no joint jump larger than vmax * dt.
            assert np.all(np.abs(cmd.q - q_robot) <= robot.vmax * 0.002 + 1e-9), sid
        assert first["shadow"].algo == "wqp"
        # Now targets arrive (a small offset from where the robot is): both track.
        for q in got.values():
            while not q.empty():
                q.get()
        seen = {"main": []}
        t_end = time.monotonic() + 1.5
        seq = 0
        while time.monotonic() < t_end:
            seq += 1
            targets = {
                n: Target(f.p + np.array([0.0, 0.0, 0.02]), f.q, np.zeros(3), np.zeros(3)) for n, f in frames.items()
            }
            target_pub.put(TaskTargets(Header(seq, seq / 100), targets).encode())
            while not got["main"].empty():
                cmd = got["main"].get()
                seen["main"].append(cmd)
                followed["q"] = cmd.q
            publish_state()
            time.sleep(0.01)
        for sid, q in got.items():
            cmds = list(seen.get(sid, []))
            while not q.empty():
                cmds.append(q.get())
            assert len(cmds) > 200, f"{sid}: only {len(cmds)} commands in 1.5 s"  # 500 Hz nominal, lenient under load
            assert cmds[-1].status in ("ok", "infeasible"), cmds[-1].reason
            assert cmds[-1].hdr.seq > 0
            qs = np.array([c.q for c in cmds])
            assert np.all(qs >= robot.lower - 1e-12) and np.all(qs <= robot.upper + 1e-12)
            assert np.all(np.abs(np.diff(qs, axis=0)) <= robot.vmax * 0.002 + 1e-9)
    finally:
        codes = [_stop(p) for p in procs]
        client.close()
    assert codes == [0, 0]
