"""RerunLogger on real messages (real MuJoCo sim states, real G1 meshes), read back from the .rrd."""

from __future__ import annotations

import math
import time

import msgpack
import numpy as np
import pytest
import rerun as rr

from services.logger.rerun_logger import RerunLogger, blueprint
from services.logger.robot_visual import RobotVisual
from services.logger.rrd_summary import scalar_rows, summarize
from services.sim.sim_core import SimConfig, SimCore
from shared.messages import (
    HUMAN_BONES,
    Bone,
    Header,
    HumanFrame,
    JointCommand,
    Pose,
    ServiceStatus,
    Target,
    TaskTargets,
)
from shared.targets import TARGET_NAMES

IDENT = np.array([1.0, 0.0, 0.0, 0.0])
N = 40
DT = 0.01  # 100 Hz source
WRIST_OFFSET = np.array([0.03, 0.0, 0.0])  # targets placed 3 cm from where the sim's wrist is


@pytest.fixture(scope="module")
def visual():
    return RobotVisual()


def make_sequence(n: int = N, expected: list | None = None):
    """Encoded payloads in bus order for n mocap frames through a real sim.

    ``expected`` (if given) receives, per frame, the (4,) error [cm] of the frame's last
    RobotState against its targets, computed here independently of the logger.
    """
    core = SimCore(config=SimConfig(watchdog=1.0))
    rng = np.random.default_rng(0)
    q0 = core.q.copy()
    out = []
    for k in range(n):
        hdr = Header(k, k * DT, time.time_ns() - 5_000_000)  # entered the bus 5 ms ago
        bones = {b: Bone(rng.normal(0, 0.3, 3), IDENT, valid=(b != "left_hand")) for b in HUMAN_BONES}
        out.append(HumanFrame(hdr, "test", Pose(np.zeros(3), IDENT), bones).encode())
        frames = core.state().frames
        targets = {
            t: Target(frames[t].p + (WRIST_OFFSET if t == "left_wrist" else 0.0), frames[t].q, np.zeros(3), np.zeros(3))
            for t in TARGET_NAMES
        }
        out.append(TaskTargets(hdr, targets).encode())
        # An elbow swinging about the start pose (about the measured pose, the swings added up and walked the elbow
        # into its stop once the servo followed them faster than 4 rad/s: commands rejected for the limits).
        q = q0.copy()
        q[core.joint_names.index(core.robot.profile.arms["left"].elbow)] += 0.2 * math.sin(k / 5)
        for sid in ("main", "alt"):
            cmd = JointCommand(hdr, sid, "hqp", list(core.joint_names), q, 0 * q, [1e-3, 2e-3, 5e-2], 0.2)
            out.append(cmd.encode())
            if sid == "main":
                core.apply(cmd)
                out.append(cmd.encode())  # solvers tick faster than frames: same seq again
        # The sim publishes faster than commands arrive: a state right after applying, one
        # half a frame later; the error is that of the last one.
        out.append(core.state().encode())
        core.step_physics(round(DT / core.dt / 2))
        last = core.state()
        out.append(last.encode())
        if expected is not None:
            expected.append([100 * np.linalg.norm(last.frames[t].p - targets[t].p) for t in TARGET_NAMES])
        core.step_physics(round(DT / core.dt / 2))
    # Two statuses 0.5 s apart: 150 more skipped by design, 2 samples lost on the bus, 1 rejected.
    out.append(ServiceStatus("solver", "main", "ok", 1.0, counts={"dropped": 3}).encode())
    st = ServiceStatus("solver", "main", "ok", 1.5, counts={"dropped": 153, "gaps": 2, "rejected": 1})
    out.append(st.encode())
    return out


def test_logs_a_real_sequence_and_reads_it_back(tmp_path, visual):
    rrd = tmp_path / "t.rrd"
    rec = rr.RecordingStream("mimic_test")
    rec.save(str(rrd))
    rec.send_blueprint(blueprint())
    lg = RerunLogger(rec, visual, robot_rate=50.0, skeleton_rate=0.0)
    expected: list = []
    payloads = make_sequence(expected=expected)
    bad = [b"\x00garbage", msgpack.packb({"v": 99, "t": "HumanFrame"}), msgpack.packb({"v": 1, "t": "Nope"})]
    for p in payloads + bad:
        lg.step("mimic/test/x", p)
    lg.flush_error()
    rec.flush()
    rec.disconnect()

    assert lg.counts["HumanFrame"] == N and lg.counts["TaskTargets"] == N
    assert lg.counts["JointCommand"] == 2 * N and lg.counts["RobotState"] == N
    assert lg.counts["decimated"] == 2 * N  # the repeated states and commands
    assert lg.rejects == {"unknown_type": 2, "version": 1}

    s = summarize(rrd)
    for ent in (
        "/world/operator/skeleton",
        "/world/operator/joints",
        "/world/robot/targets/left_wrist",
        "/world/robot/targets/right_wrist",
        "/world/robot/targets/elbows",
        "/world/robot/achieved",
        "/metrics/error_cm",
        "/metrics/latency_ms/mocap",
        "/metrics/latency_ms/state",
    ):
        assert s.rows.get(ent) == N, (ent, s.rows.get(ent))
    assert s.rows["/metrics/residual/main"] == N and s.rows["/metrics/residual/alt"] == N
    assert s.rows["/metrics/solve_ms/main"] == N and s.rows["/metrics/solve_ms/alt"] == N
    # Statuses as rates over their period, what to worry about apart from the by-design skips.
    assert "/metrics/drops/solver" not in s.rows  # no cumulative count that only ever climbs
    for ent, rate in (
        ("metrics/skipped_by_design/solver", 300.0),
        ("metrics/lost_or_rejected/solver/lost", 4.0),
        ("metrics/lost_or_rejected/solver/rejected", 2.0),
    ):
        _, v = scalar_rows(rrd, ent)
        assert v.ravel().tolist() == pytest.approx([rate]), (ent, v)  # one row: none on the first status
    assert {"seq", "stamp"} <= s.timelines["/metrics/error_cm"]
    # Robot meshes: every mesh once (static), moving ones posed at 50 Hz of a 100 Hz source.
    moving = [m for m in visual.meshes if m.moving]
    fixed = [m for m in visual.meshes if not m.moving]
    assert moving and fixed
    for robot in ("command", "sim"):
        for m in moving:
            assert s.rows[f"/world/robot/{robot}/{m.name}"] == N // 2
        for m in fixed:
            assert f"/world/robot/{robot}/{m.name}" not in s.rows
            assert s.static[f"/world/robot/{robot}/{m.name}"] >= 2  # mesh + its fixed placement

    # Values: the error of each frame's last state, as computed beside the sim.
    seq, err = scalar_rows(rrd, "metrics/error_cm")
    assert list(seq) == list(range(N))
    assert np.allclose(err, np.array(expected), atol=1e-6)
    # The left wrist target sits 3 cm off, so its error is of that size (the robot barely moves).
    assert np.all(np.abs(err[:, TARGET_NAMES.index("left_wrist")] - 100 * WRIST_OFFSET[0]) < 1.0)
    _, res = scalar_rows(rrd, "metrics/residual/main")
    assert res.shape == (N, 3) and np.allclose(res[0], [1e-3, 2e-3, 5e-2])
    _, lat = scalar_rows(rrd, "metrics/latency_ms/mocap")
    assert np.all(lat > 4.0) and np.all(lat < 5000.0)
    stamp, _ = scalar_rows(rrd, "metrics/solve_ms/main", timeline="stamp")
    assert np.allclose(stamp, np.arange(N) * DT)


def test_skeleton_is_decimated_before_decoding(tmp_path):
    rec = rr.RecordingStream("mimic_test")
    rec.save(str(tmp_path / "d.rrd"))
    lg = RerunLogger(rec, None, skeleton_rate=25.0)
    for k in range(100):  # 1 s at 100 Hz
        bones = {b: Bone(np.zeros(3), IDENT) for b in HUMAN_BONES}
        lg.step("k", HumanFrame(Header(k, k * DT), "t", Pose(np.zeros(3), IDENT), bones).encode())
    rec.flush()
    rec.disconnect()
    assert lg.counts["HumanFrame"] == 25 and lg.counts["decimated"] == 75
    assert summarize(tmp_path / "d.rrd").rows["/world/operator/skeleton"] == 25


def test_session_timeline_keeps_increasing_across_clips_and_problems_are_said_once(tmp_path):
    """Two clips (seq and stamp start again) lie one after the other on "session", not on top of
    each other as on "seq"; a degraded service is put in the text log once per change."""
    rec = rr.RecordingStream("mimic_test")
    rec.save(str(tmp_path / "s.rrd"))
    lg = RerunLogger(rec, None, skeleton_rate=0.0)
    t0 = time.time_ns()
    bones = {b: Bone(np.zeros(3), IDENT) for b in HUMAN_BONES}
    for clip in range(2):
        for k in range(20):
            hdr = Header(k, k * DT, t0 + (clip * 20 + k) * 10_000_000)
            lg.step("k", HumanFrame(hdr, f"clip{clip}", Pose(np.zeros(3), IDENT), bones).encode())
    bad = ServiceStatus("retarget", "main", "degraded", 1.0, last_error="uncalibrated: bone 'x' missing")
    for st in (bad, bad, ServiceStatus("retarget", "main", "ok", 2.0), bad):
        lg.step("s", st.encode())
    rec.flush()
    rec.disconnect()
    seq, _ = scalar_rows(tmp_path / "s.rrd", "metrics/latency_ms/mocap", timeline="seq")
    session, _ = scalar_rows(tmp_path / "s.rrd", "metrics/latency_ms/mocap", timeline="session")
    assert len(session) == 40 and len(set(seq.tolist())) == 20  # on "seq" the clips overlap
    assert np.all(np.diff(session) > 0) and session[-1] - session[0] == pytest.approx(0.39e9, rel=1e-6)
    assert summarize(tmp_path / "s.rrd").rows["/status/retarget"] == 2  # degraded, then again after ok
