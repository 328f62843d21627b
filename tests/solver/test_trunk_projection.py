"""Wrist targets projected onto the waist-carried trunk where it is now (``SolverConfig.trunk_projection``,
``services/solver/trunk_projection.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import SolverConfig, SolverCore
from services.solver.targets import TargetSample
from services.solver.trunk_projection import TrunkProjection
from shared.messages import Header, Target, TaskTargets
from shared.rotations import matrix_to_quat
from tests.retarget.conftest import torso_front

#: Distance tolerance [m] of the projected hand against the clearance (the Newton steps stop within 0.2 mm).
TOL = 5e-4
DT = 0.002


@pytest.fixture(scope="module")
def proj(robot17):
    return TrunkProjection(robot17)


@pytest.fixture(scope="module")
def turned(robot17):
    """A turned waist (yaw 0.5 rad, pitch 0.2 rad; the arms at rest): q (17,)."""
    q = robot17.q_rest.copy()
    j = {n: i for i, n in enumerate(robot17.joint_names)}
    q[j["waist_yaw_joint"]] = 0.5
    q[j["waist_pitch_joint"]] = 0.2
    return q


def _carrier(robot, proj, q):
    """The trunk's carrier pose at q: (p (3,), R (3, 3)), base frame."""
    return robot.frame_poses(q, names=(proj.carrier,))[proj.carrier]


def _to_current(proj, p_rest, R_rest):
    """A point and orientation given at the waist's rest mapped to the carrier's pose of the last set_carrier."""
    A, b = proj._A, proj._b
    return A.T @ (p_rest - b), A.T @ R_rest


@pytest.fixture(scope="module")
def hand_down(robot17):
    """The left wrist target's orientation at the rest pose (3, 3): the hand hanging, pointing forward-down."""
    return robot17.frame_poses(robot17.q_rest, names=("left_wrist",))["left_wrist"][1]


def test_the_trunk_is_what_the_waist_carries(proj):
    assert proj.carrier == "torso_link"
    assert proj.trunk.trunk == ["head_link", "logo_link", "torso_link"]  # not the pelvis: no joint moves it


def test_a_target_inside_the_turned_torso_goes_to_its_surface(robot17, proj, turned, hand_down):
    """The hand 3 cm inside the front of a torso turned by the waist: projected onto that torso's surface plus the
    clearance, along the turned front's normal (checked in MuJoCo's own pose of the torso, not the map)."""
    proj.set_carrier(*_carrier(robot17, proj, turned))
    p_rest, normal = torso_front(proj.trunk, hand_down, depth=0.03)
    p, R = _to_current(proj, p_rest, hand_down)
    assert np.linalg.norm(p - p_rest) > 0.05  # the turn moved the torso's front a lot: the rest pose is wrong
    out = proj.project("left", p, R)
    move = out - p
    assert np.linalg.norm(move) == pytest.approx(0.03 + proj.clearance, abs=2e-3)
    n_now = proj._A.T @ normal  # the front's normal as the waist turned it
    assert move @ n_now / np.linalg.norm(move) > 0.99
    # independently: MuJoCo's torso at q and at rest (the collision model) takes the result back to the rest pose
    sca = proj_sca(robot17)
    sca.set_q(turned)
    b = sca.model.body("torso_link").id
    o_q, R_q = sca.data.xpos[b].copy(), sca.data.xmat[b].reshape(3, 3).copy()
    sca.set_q(robot17.q_rest)
    o_0, R_0 = sca.data.xpos[b].copy(), sca.data.xmat[b].reshape(3, 3).copy()
    back = R_0 @ R_q.T @ (out - o_q) + o_0
    assert proj.trunk.nearest("left", back, R_0 @ R_q.T @ R)[0] == pytest.approx(proj.clearance, abs=TOL)


_SCA = {}


def proj_sca(robot):
    from services.solver.collision import SelfCollisionAvoidance

    if "sca" not in _SCA:
        _SCA["sca"] = SelfCollisionAvoidance(robot)
    return _SCA["sca"]


def test_a_target_clear_of_the_trunk_is_untouched(robot17, proj, turned, hand_down):
    proj.set_carrier(*_carrier(robot17, proj, turned))
    p_rest, _ = torso_front(proj.trunk, hand_down, depth=-0.05)
    p, R = _to_current(proj, p_rest, hand_down)
    assert proj.project("left", p, R) is p
    s = TargetSample(p, R, np.array([0.1, 0.2, 0.3]), np.zeros(3), True, False)
    assert proj.sample("left", s, R) is s  # bit for bit: the same sample object
    assert not proj.moved


def test_a_target_sliding_into_the_turned_torso_moves_continuously(robot17, proj, turned, hand_down):
    """From 5 cm outside to 8 cm inside in 1 mm steps (and 0.3 mm along the front): no projected step longer than
    1.5 times the target's, and every projected hand at the clearance or beyond."""
    proj.set_carrier(*_carrier(robot17, proj, turned))
    p0_rest, normal = torso_front(proj.trunk, hand_down, depth=-0.05)
    slide = np.array([0.0, 0.3, -1.0])
    slide -= (slide @ normal) * normal
    slide /= np.linalg.norm(slide)
    steps_in = [p0_rest - normal * (0.001 * k) + slide * (0.0003 * k) for k in range(131)]
    ps = [_to_current(proj, p, hand_down) for p in steps_in]
    outs = np.array([proj.project("left", p, R) for p, R in ps])
    step_in = np.linalg.norm(ps[1][0] - ps[0][0])
    assert np.linalg.norm(np.diff(outs, axis=0), axis=1).max() <= 1.5 * step_in
    A, b = proj._A, proj._b
    for o in outs:
        assert proj.trunk.nearest("left", A @ o + b, hand_down)[0] > proj.clearance - TOL
    assert np.linalg.norm(outs[-1] - ps[-1][0]) > 0.07  # the last target, 8 cm in, did move


def test_the_inward_velocity_is_removed(robot17, proj, turned, hand_down):
    """A projected target keeps its velocity's part along the surface (square to the exit direction ``u``, the
    move's direction) and loses the part into the body; a velocity out of the body is kept whole."""
    proj.set_carrier(*_carrier(robot17, proj, turned))
    p_rest, normal = torso_front(proj.trunk, hand_down, depth=0.02)
    p, R = _to_current(proj, p_rest, hand_down)
    n_now = proj._A.T @ normal
    along = np.cross(n_now, [0.0, 0.0, 1.0])
    along /= np.linalg.norm(along)
    v = -0.3 * n_now + 0.1 * along
    out = proj.sample("left", TargetSample(p, R, v, np.zeros(3), True, False), R)
    u = (out.p - p) / np.linalg.norm(out.p - p)
    assert u @ n_now > 0.99  # out through the front
    assert out.v @ u == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(out.v, v - (v @ u) * u, atol=1e-15)
    assert proj.moved["left"] == pytest.approx(0.02 + proj.clearance, abs=2e-3)
    leaving = 0.3 * n_now + 0.1 * along
    assert proj.sample("left", TargetSample(p, R, leaving, np.zeros(3), True, False), R).v is leaving


def _targets(poses, left_p, seq, t):
    out = {}
    for n, (p, R) in poses.items():
        p = left_p if n == "left_wrist" else p
        out[n] = Target(np.asarray(p, float), matrix_to_quat(R), np.zeros(3), np.zeros(3), True, False)
    return TaskTargets(Header(seq, t), out)


def _drive(robot, target, projection, ticks=1000):
    # Strict on every tick: what the projection is measured against. (With the shipped saturation trade the
    # unprojected run turns the waist less, 0.34 rad, and the projected one 0.39.)
    cfg = SolverConfig(algo="hqp-nullspace", qp="daqp", trunk_projection=projection, saturation_weight=0.0)
    core = SolverCore(robot, cfg)
    core.reset(robot.q_rest)
    poses = robot.frame_poses(robot.q_rest)
    cmds = [core.step(_targets(poses, target, k, k * DT), None, k * DT) for k in range(ticks)]
    return cmds, core


def test_solver_tracks_a_belly_target_at_the_surface_without_turning_the_waist(robot17):
    """A left wrist target 5 cm in front of the torso's origin at belly height (inside the torso): with the
    projection the wrist level is met at the surface, status ``surface``; the waist turns less than without."""
    robot17.forward(robot17.q_rest)
    inside = robot17.data.oMf[robot17.model.getFrameId("torso_link")].translation + np.array([0.05, 0.0, 0.05])
    waist = [robot17.joint_names.index(j) for j in robot17.profile.waist]
    cmds, core = _drive(robot17, inside, True)
    last = cmds[-1]
    assert last.status == "surface", (last.status, last.reason)
    assert "inside the body" in last.reason and "left wrist" in last.reason
    assert core.counts["surface_ticks"] > 900
    wrist = core.configuration.get_frame_pose("left_wrist")[0]
    assert np.linalg.norm(wrist - core.wrist_tasks[0].p_target) < 1e-3  # level 1 met, on the projected target
    assert np.linalg.norm(wrist - inside) > 0.02  # which is out of the body
    off, _ = _drive(robot17, inside, False)
    turn_on = np.abs(last.q[waist] - robot17.q_rest[waist]).max()
    turn_off = np.abs(off[-1].q[waist] - robot17.q_rest[waist]).max()
    # 0.39 against 0.49 rad (0.25 while the wrist point was the hand link, 4.6 cm further out; 0.23 with per-link
    # exit rays)
    assert turn_on < 0.9 * turn_off, (turn_on, turn_off)
    assert {c.status for c in off} <= {"ok", "collision", "infeasible"}  # off: no surface status


def test_a_target_outside_leaves_the_solver_unchanged(robot17):
    """Targets clear of the body: the same commands, bit for bit, with the projection on or off."""
    poses = robot17.frame_poses(robot17.q_rest)
    p = poses["left_wrist"][0] + np.array([0.1, 0.05, 0.05])
    on, _ = _drive(robot17, p, True, 200)
    off, _ = _drive(robot17, p, False, 200)
    assert all(np.array_equal(a.q, b.q) and a.status == b.status for a, b in zip(on, off, strict=True))
