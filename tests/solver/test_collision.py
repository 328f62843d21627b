"""Self-collision avoidance: distances, witness Jacobians, dampers in the solver (known answers)."""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest

from services.solver.collision import (
    SelfCollisionAvoidance,
    add_proxy_geom,
    link_proxy,
    primitive_points,
    proxy_contacts,
)
from services.solver.core import SolverConfig, SolverCore
from services.solver.inequalities import Inequalities
from shared.messages import Header, Target, TaskTargets
from shared.mirror import arm_joints
from shared.robot.pinocchio_model import build_robot_model
from shared.rotations import matrix_to_quat

DT = 0.002


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


@pytest.fixture(scope="module")
def avoidance(robot):
    return SelfCollisionAvoidance(robot)


def _capsule_surface(p0, p1, r, n=4000, seed=0):
    """(n, 3) points on the surface of the capsule (p0, p1, r): half on its cylinder, half on its end caps."""
    rng = np.random.default_rng(seed)
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    side = u - (u @ axis)[:, None] * axis
    side /= np.linalg.norm(side, axis=1)[:, None]
    cylinder = p0 + rng.uniform(0, 1, (n, 1)) * (p1 - p0) + r * side
    caps = np.where((u @ axis > 0)[:, None], p1 + r * u, p0 + r * u)
    return np.where(rng.uniform(size=(n, 1)) < 0.5, cylinder, caps)


def test_polytope_holds_the_hull_and_touches_it():
    # A 30 x 20 x 10 cm box: the polytope holds every vertex, its 6 principal faces lie on the box's faces,
    # and its vertices are the box's corners (no face sticks out of a box).
    corners = np.array([[x, y, z] for x in (-0.15, 0.15) for y in (-0.1, 0.1) for z in (-0.05, 0.05)])
    px = link_proxy(corners)
    assert np.all(corners @ px.normals.T <= px.offsets + 1e-12)
    assert np.allclose(np.sort(px.offsets[:6]), [0.05, 0.05, 0.1, 0.1, 0.15, 0.15])
    assert np.allclose(np.sort(np.abs(px.vertices()), axis=0).max(axis=0), [0.15, 0.1, 0.05], atol=1e-9)


def test_cylinder_geom_proxy_holds_the_cylinder_and_hugs_it():
    # A MuJoCo cylinder of radius 3 cm, half height 2.5 cm (the G1's shoulder pitch link): the proxy of its points
    # holds every point of its surface, reaches no farther than 1 mm past it in any direction, and is flat on
    # its ends; a kind the proxies do not fit says so.
    pts = primitive_points(mujoco.mjtGeom.mjGEOM_CYLINDER, np.array([0.03, 0.025, 0.0]))
    px = link_proxy(pts)
    rng = np.random.default_rng(2)
    phi, z = rng.uniform(0, 2 * np.pi, 5000), rng.uniform(-0.025, 0.025, 5000)
    side = np.stack((0.03 * np.cos(phi), 0.03 * np.sin(phi), z), axis=1)
    assert np.all(side @ px.normals.T <= px.offsets + 1e-12)
    d = px.normals
    # the cylinder's support along each face normal: radius times the radial part plus half height times |n_z|
    support = 0.03 * np.linalg.norm(d[:, :2], axis=1) + 0.025 * np.abs(d[:, 2])
    assert np.all(px.offsets >= support - 1e-12) and np.max(px.offsets - support) < 1e-3
    assert np.isclose(np.abs(px.vertices()[:, 2]).max(), 0.025)
    assert primitive_points(mujoco.mjtGeom.mjGEOM_ELLIPSOID, np.array([0.03, 0.02, 0.01])) is None


TWO_LINKS = """
<mujoco>
  <worldbody>
    <body name="a"><joint name="ja" type="slide" axis="1 0 0"/>
      <inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body>
    <body name="b" pos="0.1 0 0"><joint name="jb" type="hinge" axis="0 0 1" pos="-0.1 0 0"/>
      <inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body>
  </worldbody>
</mujoco>
"""


@pytest.mark.parametrize("x_a, expected", [(0.0, 0.0), (-0.05, 0.05), (0.01, -0.01)])
def test_touching_capsules_known_answers(x_a, expected):
    # Two links whose meshes are capsules of radius 5 cm, axes 10 cm apart (a along z, b along y), fitted
    # like the robot's: polytope against polytope. Touching (0), 5 cm apart, 1 cm into each other: the
    # polytopes stand for the round capsules within 3 mm, and never farther.
    spec = mujoco.MjSpec.from_string(TWO_LINKS)
    pa = link_proxy(_capsule_surface(np.array([0, 0, -0.1]), np.array([0, 0, 0.1]), 0.05, seed=1))
    pb = link_proxy(_capsule_surface(np.array([0, -0.1, 0]), np.array([0, 0.1, 0]), 0.05, seed=2))
    pair = spec.add_pair()
    pair.geomname1, pair.geomname2, pair.margin = add_proxy_geom(spec, "a", pa), add_proxy_geom(spec, "b", pb), 1.0
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qpos[0] = x_a
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    dist, normal, p1, p2, bodies = proxy_contacts(m, d)
    assert dist.shape == (1,) and bodies == [[m.body("a").id, m.body("b").id]]
    assert expected - 0.003 <= dist[0] <= expected + 1e-4  # measured 1.3 mm under when touching
    assert normal[0] @ [1, 0, 0] > 0.999  # a towards b (the polytopes' nearest faces, within 3 degrees)
    assert np.allclose(p2[0] - p1[0], dist[0] * normal[0])
    # d_dot when a slides along +x: the pair closes at n_x m/s whatever the sign of d.
    ja, jb = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jac(m, d, ja, None, p1[0], bodies[0][0])
    mujoco.mj_jac(m, d, jb, None, p2[0], bodies[0][1])
    assert normal[0] @ (jb - ja)[:, 0] == pytest.approx(-normal[0, 0], abs=1e-9)


def test_witness_jacobian_matches_finite_differences(robot, avoidance):
    # The row is the distance's gradient wherever the distance is smooth; a polytope's distance has kinks
    # where the nearest face changes, so a few random poses may sit on one (measured: 1-2 in 60).
    rng = np.random.default_rng(4)
    h = 1e-6

    def dist(q, pair):
        for p in avoidance.distances(q):
            if (p.body_a, p.body_b) == pair:
                return p.distance
        raise AssertionError("pair lost")

    matched = []
    for q in robot.random_configurations(80, rng):
        pds = [p for p in avoidance.distances(q) if p.distance > 0.005]  # separated
        if not pds:
            continue
        pd = pds[0]
        g = avoidance.distance_jacobian(pd)
        pair = (pd.body_a, pd.body_b)
        fd = np.zeros(robot.nq)
        for j in range(robot.nq):
            dq = np.zeros(robot.nq)
            dq[j] = h
            fd[j] = (dist(q + dq, pair) - dist(q - dq, pair)) / (2 * h)
        matched.append(np.allclose(g, fd, atol=1e-4))
    assert len(matched) >= 20
    assert np.mean(matched) >= 0.9, matched


def test_proxy_distance_never_exceeds_the_mesh_distance(robot, avoidance):
    # The proxies hold the meshes' hulls: on random poses every pair within d_i is no farther than its
    # meshes (mj_geomDistance), and not much nearer (measured mean 0.2 cm, in the module docstring).
    rng = np.random.default_rng(5)
    under = []
    for q in robot.random_configurations(150, rng):
        for pd in avoidance.distances(q):
            a, b = avoidance.body_names(pd)
            mesh = avoidance.mesh_distance(a, b)
            if mesh >= 0.0:
                assert pd.distance <= mesh + 2e-4, (a, b, pd.distance, mesh)
                under.append(mesh - pd.distance)
    assert len(under) > 300
    assert np.mean(under) < 0.004


def test_rows_are_the_damper(robot, avoidance):
    # Every pair within d_i gives one row, h = the dampers' bound at its distance (known answers in the next test),
    # G = -(its distance gradient).
    rng = np.random.default_rng(6)
    for q in robot.random_configurations(50, rng):
        ineq = avoidance.rows(q)
        if ineq.rows >= 2:
            break
    spec = avoidance.spec
    assert ineq.rows == len(avoidance.close) >= 2
    for r, pd in enumerate(avoidance.close):
        assert pd.distance < spec.influence_distance
        assert ineq.h[r] == pytest.approx(avoidance.approach_bound(np.array([pd.distance]))[0])
        assert np.allclose(-ineq.G[r], avoidance.distance_jacobian(pd))


def test_approach_bound_known_answers(robot, avoidance):
    # The G1's dampers (d_s 1.5, d_b 2.5, d_i 8 cm, xi 1 m/s) with a = 20 m/s^2 (the profile ships 0): the linear
    # damper up to d_b and wherever it allows more, the braking curve sqrt(2 a (d - d_b)) beyond; a = 0 (shipped)
    # leaves the linear damper alone.
    spec = robot.profile.collision
    assert (spec.safety_distance, spec.braking_distance, spec.influence_distance) == (0.015, 0.025, 0.08)
    assert (spec.damper_speed, spec.braking_deceleration) == (1.0, 0.0)
    d = np.array([0.010, 0.020, 0.045, 0.075])
    assert np.allclose(avoidance.approach_bound(d), [-1 / 13, 1 / 13, 6 / 13, 12 / 13])
    braking = copy.copy(avoidance)
    braking.decel = 20.0
    # 1 cm: must separate at 5/65 m/s; 2 cm: linear 5/65; 4.5 cm: sqrt(40 * 0.02) = 0.894 > linear 30/65;
    # 7.5 cm: sqrt(40 * 0.05) = 1.414 > linear 60/65
    assert np.allclose(braking.approach_bound(d), [-1 / 13, 1 / 13, np.sqrt(0.8), np.sqrt(2.0)])


def test_rows_the_box_cannot_break_are_dropped(robot, avoidance):
    # With a small velocity box, the rows no velocity in it can break are dropped; those kept can be broken.
    rng = np.random.default_rng(7)
    for q in robot.random_configurations(80, rng):
        full = avoidance.rows(q)
        if full.rows >= 2 and min(pd.distance for pd in avoidance.close) > avoidance.d_s:
            break
    lb, ub = np.full(robot.nq, -0.05), np.full(robot.nq, 0.05)
    kept = avoidance.rows(q, lb, ub)
    assert kept.rows < full.rows
    most = np.maximum(kept.G * lb, kept.G * ub).sum(axis=1)
    assert np.all(most > kept.h)
    assert len(avoidance.close) == kept.rows


def test_relaxed_rows_stay_feasible_with_the_box():
    G = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, -1.0]])
    ineq = Inequalities(G, np.array([-2.0, 0.5, -3.0]))
    x0 = np.array([0.5, 0.5])
    ineq.relax_to(x0)
    assert ineq.satisfied(x0)
    assert ineq.h[1] == pytest.approx(0.5 + 1e-6)  # a row x0 already met up to the slack keeps (about) its value


def _wrist_targets(robot, q_rest_poses, left_p, seq, t):
    """The rest pose's targets with the left wrist moved to left_p (3,) [m] (elbows at rest)."""
    out = {}
    for n, (p, R) in q_rest_poses.items():
        p = left_p if n == "left_wrist" else p
        out[n] = Target(np.asarray(p, float), matrix_to_quat(R), np.zeros(3), np.zeros(3), True, False)
    return TaskTargets(Header(seq, t), out)


def _clearance(avoidance, q) -> float:
    """The smallest proxy distance [m] (what the dampers hold), capped at 0.3."""
    pds = avoidance.distances(q, 0.3)
    return pds[0].distance if pds else 0.3


def _mesh_clearance(avoidance, q) -> float:
    """The smallest distance [m] of the pairs' collision meshes (mj_geomDistance), capped at 0.3."""
    avoidance.set_q(q)
    links = avoidance.links
    return min(avoidance.mesh_distance(links[a], links[b], 0.3) for a, b in avoidance.link_pairs)


def _drive(robot, avoidance, points, ticks_each, algo="hqp-nullspace"):
    """Closed loop (the solver integrates its own command) through the left-wrist targets; returns commands and the
    smallest mesh clearance of the commanded joints."""
    core = SolverCore(robot, SolverConfig(algo=algo, qp="daqp", self_collision=True))
    core.reset(robot.q_rest)
    poses = robot.frame_poses(robot.q_rest)
    cmds, clear = [], np.inf
    k = 0
    for p in points:
        for _ in range(ticks_each):
            cmd = core.step(_wrist_targets(robot, poses, p, k, k * DT), None, k * DT)
            cmds.append(cmd)
            if k % 5 == 0:
                clear = min(clear, _mesh_clearance(avoidance, cmd.q))
            k += 1
    return cmds, clear, core


def test_target_inside_the_torso_stops_at_the_safety_distance(robot, avoidance):
    torso = robot.model.getFrameId("torso_link")
    robot.forward(robot.q_rest)
    inside = robot.data.oMf[torso].translation + np.array([0.05, 0.0, 0.15])  # the chest, inside the torso mesh
    cmds, clear, core = _drive(robot, avoidance, [inside], 1000)
    d_s = robot.profile.collision.safety_distance
    final = _clearance(avoidance, cmds[-1].q)
    assert final == pytest.approx(d_s, abs=0.004)  # the proxies stopped at the safety distance
    assert _mesh_clearance(avoidance, cmds[-1].q) >= final - 2e-4  # the meshes no nearer than their proxies
    assert clear > 0.0  # never through it
    assert cmds[-1].status == "collision"
    assert "self-collision" in cmds[-1].reason and "left" in cmds[-1].reason
    # the eval's account of the tick (goal causes): the damper holds joints of the left arm, none of the right's
    _holds, held = core.tick_holds()
    assert held[arm_joints(robot, "left")].any() and not held[arm_joints(robot, "right")].any()


@pytest.mark.parametrize("algo", ["hqp-nullspace", "wqp"])
def test_no_penetration_driving_a_hand_into_torso_and_other_arm(robot, avoidance, algo):
    poses = robot.frame_poses(robot.q_rest)
    torso = robot.model.getFrameId("torso_link")
    robot.forward(robot.q_rest)
    chest = robot.data.oMf[torso].translation + np.array([0.05, 0.0, 0.12])
    right_elbow = poses["right_elbow"][0]
    right_wrist = poses["right_wrist"][0]
    points = [chest, right_elbow, right_wrist, chest + np.array([0.0, 0.0, -0.25])]  # chest, other arm, pelvis
    cmds, clear, _core = _drive(robot, avoidance, points, 300, algo)
    assert clear >= 0.0, clear
    statuses = {c.status for c in cmds}
    assert "collision" in statuses and "failed" not in statuses


def test_without_avoidance_the_same_drive_penetrates(robot, avoidance):
    # The damper is what keeps the hand out: the same targets without it go into the torso.
    torso = robot.model.getFrameId("torso_link")
    robot.forward(robot.q_rest)
    inside = robot.data.oMf[torso].translation + np.array([0.05, 0.0, 0.15])
    core = SolverCore(robot, SolverConfig(qp="daqp", self_collision=False))
    core.reset(robot.q_rest)
    poses = robot.frame_poses(robot.q_rest)
    for k in range(600):
        cmd = core.step(_wrist_targets(robot, poses, inside, k, k * DT), None, k * DT)
    assert _mesh_clearance(avoidance, cmd.q) < 0.0


def test_rows_between_measurements_follow_the_joints(robot, avoidance):
    # Along a joint path that brings pairs within d_i in steps of one 500 Hz tick at 2 rad/s summed, the pairs are
    # measured again only when the links could have closed the pad; in between, every pair a fresh measurement
    # finds within d_i is among the rows (but on the edge of d_i), its followed distance within a millimetre.
    rng = np.random.default_rng(11)
    for q1 in robot.random_configurations(200, rng):
        if len(avoidance.distances(q1)) >= 2:
            break
    q0 = robot.q_rest.copy()
    step = 2.0 * DT  # [rad] of summed joint travel a tick
    n = int(np.abs(q1 - q0).sum() / step) + 1
    before = avoidance.measurements
    fresh = SelfCollisionAvoidance(robot)
    worst = 0.0
    for s in np.linspace(0.0, 1.0, n):
        q = q0 + s * (q1 - q0)
        avoidance.rows(q)
        followed = {(pd.body_a, pd.body_b): pd.distance for pd in avoidance.close}
        for pd in fresh.distances(q):
            key = (pd.body_a, pd.body_b)
            if key in followed:
                worst = max(worst, abs(followed[key] - pd.distance))
            else:  # only a pair on the edge of d_i, within the followed distance's error
                assert pd.distance > avoidance.d_i - 1e-3, (s, fresh.body_names(pd), pd.distance)
    measured = avoidance.measurements - before
    assert measured < n / 3, (measured, n)  # most ticks follow the last measurement
    assert worst < 1e-3, worst
