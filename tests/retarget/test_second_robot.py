"""A second robot is a second TOML file and nothing else: an arms-only G1 (no waist, wrist
targets on other frames) through the model, workspace, arm geometry, retargeter, solver and sim."""

from __future__ import annotations

import re

import numpy as np
import pytest
from conftest import make_frame

from services.retarget.elbow import ArmGeometry
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.retarget.workspace import load_workspace
from services.sim.sim_core import SimConfig, SimCore
from services.solver.core import SolverConfig, SolverCore
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import load_profile
from shared.targets import SIDES, TARGET_NAMES, WRISTS, elbow_of, wrist_of

#: Position error [m] once the arms-only robot has held still, reachable targets for 1 s (the
#: solver's level-1 tolerance is 1e-3 m; on this robot both errors measure below 1e-9 m).
ERR_TOL = 1e-4


def _arms_only(text: str) -> str:
    """No waist (14 DoF) and wrist targets on the hand links (position and orientation: no
    ``[orientation_frames]``) instead of the G1's wrist pitch axis and hand."""
    text = re.sub(r"^waist = \[.*\]$", "waist = []", text, count=1, flags=re.M)
    text = text.replace("[orientation_frames]", "[unused_orientation_frames]")
    for side in SIDES:
        text = text.replace(f'{side}_wrist = "{side}_wrist_pitch_link"', f'{side}_wrist = "{side}_rubber_hand"')
    return text


@pytest.fixture(scope="module")
def arms_only(tmp_path_factory):
    text = _arms_only(load_profile().source.read_text())
    path = tmp_path_factory.mktemp("profiles") / "arms_only.toml"
    path.write_text(re.sub(r'^name = ".*"$', 'name = "arms_only"', text, count=1, flags=re.M))
    return load_profile(path)


def test_arms_only_robot_runs_the_retarget_path_unchanged(arms_only, tmp_path, monkeypatch):
    """Model, workspace, arm geometry, retargeter, solver and sim on a 14-DoF robot with other wrist frames."""
    monkeypatch.setenv("MIMIC_CACHE_DIR", str(tmp_path))
    rm = build_robot_model(arms_only)
    assert rm.nq == 14 and not arms_only.waist
    assert rm.model.frames[rm.frame_id("left_wrist")].name == "left_rubber_hand" and not rm.rotation_ids
    g1 = build_robot_model(load_profile(), with_waist=False)
    rest, rest_g1 = rm.frame_poses(rm.q_rest), g1.frame_poses(g1.q_rest)
    # the hand frame sits beyond the wrist pitch axis: the profile's frame choice took effect
    for w in WRISTS:
        assert np.linalg.norm(rest[w][0] - rest_g1[w][0]) > 0.01

    ws = load_workspace(arms_only, samples=2000, robot=rm, progress=False)
    for t in TARGET_NAMES:
        assert np.all(ws.lower[t] < ws.upper[t])
    for side in SIDES:
        arm = ArmGeometry.measure(rm, side, samples=200)
        # the elbow frame really lies on the measured sphere around the shoulder centre
        e = rest[elbow_of(side)][0]
        assert abs(np.linalg.norm(e - arm.centre) - arm.upper) < 0.02
        assert arm.reach[0] < np.linalg.norm(rest[wrist_of(side)][0] - arm.centre) < arm.reach[1] + 0.02

    r = Retargeter(
        RetargetConfig(robot=str(arms_only.source), samples=2000, reach_samples=20_000), workspace=ws, robot=rm
    )
    assert r.trunk is None  # its rubber hands have no collision proxy: no trunk push (a warning), the rest runs
    solver = SolverCore(rm, SolverConfig())
    dt, out, cmd, t = solver.config.dt, None, None, 0.0
    for k in range(60):
        lift = np.array([0.2, 0.0, 0.15]) * min(1.0, k / 20)
        out = r.step(make_frame(k + 1, k / 30, offsets={"left_wrist": lift, "left_elbow": 0.5 * lift})) or out
        for j in range(round(1 / (30 * dt))):  # the solver ticks at its own rate between mocap frames
            cmd = solver.step(out if j == 0 else None, None, t)
            t += dt
    assert out is not None and all(out.targets[t].valid for t in TARGET_NAMES)
    assert len(cmd.q) == 14 and np.all((cmd.q >= rm.lower) & (cmd.q <= rm.upper))
    reached = rm.frame_poses(np.asarray(cmd.q))
    err = {w: float(np.linalg.norm(reached[w][0] - out.targets[w].p)) for w in WRISTS}
    assert max(err.values()) < ERR_TOL, err
    # the swivel elbow targets are placed at this robot's own arm lengths (measured on its frames)
    for side, arm in r.arms.items():
        e, w = out.targets[elbow_of(side)].p, out.targets[wrist_of(side)].p
        assert abs(np.linalg.norm(e - arm.centre) - arm.upper) < 1e-6
        assert abs(np.linalg.norm(w - e) - arm.fore) < 1e-6

    # the sim builds from the same file and follows the solver's command; its achieved frames are
    # the profile's (hand) frames, matching Pinocchio on the simulated q (to ~1 um: MuJoCo holds the
    # uncontrolled waist with its servo, Pinocchio locks it)
    sim = SimCore(arms_only, SimConfig(watchdog=2.0))
    assert sim.joint_names == rm.joint_names
    assert sim.apply(cmd)
    sim.step_physics(800)
    st = sim.state()
    assert np.max(np.abs(st.q - np.asarray(cmd.q))) < np.deg2rad(1.0)
    ref = rm.frame_poses(st.q)
    for t in TARGET_NAMES:
        np.testing.assert_allclose(st.frames[t].p, ref[t][0], atol=1e-5)
