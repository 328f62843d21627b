"""`mimic solve` processes on a real Zenoh bus over loopback: main + shadow, mid-stream start without a jump."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pinocchio as pin
import pytest

from services.launcher.supervisor import stop_processes
from shared.keys import Keys
from shared.messages import Header, JointCommand, Pose, RobotState, Target, TaskTargets
from shared.robot.pinocchio_model import build_robot_model
from tests.support.bus_client import BusClient, drain

pytestmark = [pytest.mark.integration, pytest.mark.slow]

#: Largest wrist distance [m] from reachable targets after 1.5 s. Measured: the HQP 6e-8 m (it meets
#: them), the weighted QP 2.4e-4 m on the merged main (twice on a quiet CI run; 4e-5 m on the solver
#: branch alone): it trades a little wrist accuracy against the elbows and orientations.
WRIST_TOL = {"main": 5e-7, "shadow": 4e-4}
TRACKING: dict[str, float] = {}


def cmds_status(cmds: list[JointCommand]) -> str:
    return cmds[-1].status


def assert_safe_over_wall_clock(robot, cmds: list[JointCommand]) -> None:
    """Positions within limits; between consecutive commands |dq| <= vmax dt and |dqd| <= a_max dt, dt from t_cmd."""
    qs = np.array([c.q for c in cmds])
    qds = np.array([c.qd for c in cmds])
    dt = np.diff([c.t_cmd for c in cmds])[:, None]
    assert np.all(dt > 0)
    assert np.all(qs >= robot.lower - 1e-12) and np.all(qs <= robot.upper + 1e-12)
    assert np.all(np.abs(qds) <= robot.vmax + 1e-9)
    assert np.all(np.abs(np.diff(qs, axis=0)) <= robot.vmax * dt + 1e-9)
    assert np.all(np.abs(np.diff(qds, axis=0)) <= robot.amax * dt + 1e-6)


TARGETS = ("left_wrist", "right_wrist", "left_elbow", "right_elbow")


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
    client = BusClient(router)
    got = {sid: client.inbox(keys.command(sid), JointCommand.decode) for sid in ("main", "shadow")}
    state_pub = client.publisher(keys.sim_state)
    target_pub = client.publisher(keys.targets)
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
            drain(q)
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
        goal = {n: robot.frame_poses(q_robot)[n][0] + np.array([0.0, 0.0, 0.02]) for n in ("left_wrist", "right_wrist")}
        for sid, q in got.items():
            cmds = [*seen.get(sid, []), *drain(q)]
            # 750 at the nominal 500 Hz; a machine loaded by other jobs (load ~25 on 2 cores) gave 116-199.
            assert len(cmds) > 100, f"{sid}: only {len(cmds)} commands in 1.5 s"
            assert cmds[-1].hdr.seq > 0
            assert_safe_over_wall_clock(robot, cmds)
            # Both track: the wrists of the last command are at the targets, 2 cm above where they started.
            poses = robot.frame_poses(cmds[-1].q)
            err = max(float(np.linalg.norm(poses[n][0] - p)) for n, p in goal.items())
            TRACKING[sid] = err
            assert err < WRIST_TOL[sid], f"{sid}: wrists {err * 1e3:.2f} mm from the targets"
        assert cmds_status(seen["main"]) == "ok", seen["main"][-1].reason
    finally:
        codes = [_stop(p) for p in procs]
        client.close()
    assert codes == [0, 0]


def test_event_trigger_ticks_on_every_target_and_stays_within_limits(router):
    """``--trigger event`` at ``--rate 50``: targets at ~200 Hz each get their own command (a 50 Hz clock
    alone would give 4x fewer), and the commands respect vmax and a_max over wall-clock time."""
    robot = build_robot_model()
    session = "solver_event"
    keys = Keys(session)
    client = BusClient(router)
    got = client.inbox(keys.command("main"), JointCommand.decode)
    target_pub = client.publisher(keys.targets)
    proc = _start(router, session, "--trigger", "event", "--rate", "50", "--qp", "daqp", "--startup-wait", "0")
    try:
        first = got.get(timeout=40)  # the 50 Hz clock runs before any target
        assert first.status == "init"
        rng = np.random.default_rng(2)
        q_goal = robot.clip(robot.q_rest + 0.3 * rng.uniform(-1, 1, robot.nq))
        poses = robot.frame_poses(q_goal)
        targets = {n: Target(p, _quat(R), np.zeros(3), np.zeros(3)) for n, (p, R) in poses.items() if n in TARGETS}
        sent = 0
        t0 = time.monotonic()
        while time.monotonic() - t0 < 2.0:
            sent += 1
            target_pub.put(TaskTargets(Header(sent, sent / 200), targets).encode())
            time.sleep(0.005)
        time.sleep(0.2)
        cmds = drain(got)
        assert proc.poll() is None, proc.stderr.read()
    finally:
        code = _stop(proc)
        client.close()
    assert code == 0
    answered = {c.hdr.seq for c in cmds if c.hdr.seq > 0}
    # The 50 Hz clock alone would answer at most 100 of the targets sent in 2 s; on every arrival it
    # answers each one it can solve in time (all of them on an idle machine).
    assert len(answered) > 1.2 * 50 * 2.0, (len(answered), sent)
    assert_safe_over_wall_clock(robot, cmds)
