"""The TITA-PiPER drawn in Rerun from its MJCF primitives (services/logger/wheeled_visual.py)."""

from __future__ import annotations

import numpy as np
import pytest
import rerun as rr

from services.logger.rerun_logger import RerunLogger
from services.logger.rrd_summary import summarize
from services.logger.wheeled_visual import WheeledVisual
from services.solver.wbqp_accel import Q_NAMES
from shared.messages import Header, Pose, RobotState


@pytest.fixture(scope="module")
def visual():
    return WheeledVisual("models/tita_piper.toml")


def test_primitives_are_the_visible_geoms(visual):
    names = {m.name for m in visual.meshes}
    assert {"torso_geom", "gripper_geom", "left_wheel_geom", "right_wheel_geom"} <= names
    assert not any("contact" in n or n == "floor" for n in names)  # invisible contact spheres, the floor


def test_pose_follows_the_seven_coordinates(visual):
    kin = visual.robot.kin
    rng = np.random.default_rng(3)
    idx = {m.name: i for i, m in enumerate(visual.meshes)}
    r = visual._wheel_r
    for _ in range(10):
        q = np.r_[
            rng.uniform(-1, 1, 2),
            rng.uniform(0.32, 0.44),
            rng.uniform(-3, 3),
            rng.uniform([-2, 0.2, -2.8], [2, 3.0, -0.2]),
        ]
        poses = visual.placements(list(Q_NAMES), q)
        p_t, R_t = poses[idx["torso_geom"]]
        assert np.allclose(p_t, q[:3]) and np.isclose(np.arctan2(R_t[1, 0], R_t[0, 0]), q[3])
        # The gripper box sits where the planner's hand kinematics put the hand (Σa is 0.06 m past its centre).
        p_g, R_g = poses[idx["gripper_geom"]]
        assert np.linalg.norm(p_g + 0.06 * R_g[:, 2] - kin.hand(q)) < 1e-9
        # The legs put both wheels on the floor under the torso.
        for w in ("left_wheel_geom", "right_wheel_geom"):
            assert abs(poses[idx[w]][0][2] - r) < 1e-6
    with pytest.raises(KeyError):
        visual.placements(["no_such_joint"], np.zeros(1))


def test_logger_draws_and_poses_the_primitives(visual, tmp_path):
    rec = rr.RecordingStream("mimic_test")
    path = tmp_path / "tita.rrd"
    rec.save(str(path))
    logger = RerunLogger(rec, visual, robot_rate=0.0)
    q = np.r_[0.2, 0.0, 0.4, 0.1, 0.0, 1.5, -2.3]
    for k in range(3):
        st = RobotState(
            Header(k + 1, 0.1 * k, 1000 + k),
            list(Q_NAMES),
            q,
            np.zeros(7),
            {"right_wrist": Pose(np.zeros(3), np.array([1.0, 0, 0, 0]))},
            0.1 * k,
        )
        assert logger.step("mimic/t/sim/state", st.encode()) == "RobotState"
    rec.flush()
    rec.disconnect()
    s = summarize(path)
    assert "/world/robot/sim/torso_geom" in s.static and "/world/robot/command/gripper_geom" in s.static
    assert s.rows.get("/world/robot/sim/torso_geom", 0) >= 1
