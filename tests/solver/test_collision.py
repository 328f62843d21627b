"""Self-collision avoidance: distances, witness Jacobians, dampers in the solver (known answers)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from services.solver.collision import SelfCollisionAvoidance, distance_gradient, pair_distance
from services.solver.core import SolverConfig, SolverCore
from services.solver.inequalities import Inequalities
from shared.messages import Header, Target, TaskTargets
from shared.robot.pinocchio_model import build_robot_model
from shared.rotations import matrix_to_quat

DT = 0.002

CAPSULES = """
<mujoco>
  <worldbody>
    <body name="a"><joint name="ja" type="slide" axis="1 0 0"/>
      <geom name="ga" type="capsule" fromto="0 0 -0.1 0 0 0.1" size="0.05"/></body>
    <body name="b" pos="0.1 0 0"><joint name="jb" type="hinge" axis="0 0 1" pos="-0.1 0 0"/>
      <geom name="gb" type="capsule" fromto="0 -0.1 0 0 0.1 0" size="0.05"/></body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


@pytest.fixture(scope="module")
def avoidance(robot):
    return SelfCollisionAvoidance(robot)


def _capsules(x_a: float):
    m = mujoco.MjModel.from_xml_string(CAPSULES)
    d = mujoco.MjData(m)
    d.qpos[0] = x_a
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    return m, d


@pytest.mark.parametrize("x_a, expected", [(0.0, 0.0), (-0.05, 0.05), (0.01, -0.01)])
def test_capsule_pair_distance_known_answers(x_a, expected):
    # Two capsules of radius 5 cm, axes 10 cm apart: touching (0), 5 cm apart, 1 cm into each other.
    m, d = _capsules(x_a)
    pd = pair_distance(m, d, 0, 1, 1.0)
    assert pd is not None
    assert pd.distance == pytest.approx(expected, abs=1e-6)
    # d_dot when a slides along +x: the pair closes at 1 m/s whatever the sign of d.
    g = distance_gradient(m, d, pd)
    assert g[0] == pytest.approx(-1.0, abs=1e-6)
    assert pair_distance(m, d, 0, 1, expected - 1e-3) is None  # beyond dmax: not reported


def test_witness_jacobian_matches_finite_differences(robot, avoidance):
    rng = np.random.default_rng(4)
    checked = 0
    for q in robot.random_configurations(60, rng):
        pds = avoidance.distances(q, 0.2)
        if not pds:
            continue
        pd = pds[0]
        g = avoidance.distance_jacobian(pd)
        fd = np.zeros(robot.nq)
        h = 1e-6
        for j in range(robot.nq):
            dq = np.zeros(robot.nq)
            dq[j] = h
            avoidance.set_q(q + dq)
            dp = pair_distance(avoidance.model, avoidance.data, pd.geom_a, pd.geom_b, 1.0).distance
            avoidance.set_q(q - dq)
            dm = pair_distance(avoidance.model, avoidance.data, pd.geom_a, pd.geom_b, 1.0).distance
            fd[j] = (dp - dm) / (2 * h)
        assert np.allclose(g, fd, atol=1e-5), (pd.distance, g - fd)
        checked += 1
    assert checked >= 20


def test_box_lower_bound_never_exceeds_the_distance(robot, avoidance):
    rng = np.random.default_rng(5)
    for q in robot.random_configurations(40, rng):
        avoidance.set_q(q)
        lower = avoidance.lower_bounds()
        for i, (a, b) in enumerate(avoidance.pairs):
            pd = pair_distance(avoidance.model, avoidance.data, int(a), int(b), 10.0)
            assert lower[i] <= pd.distance + 1e-9


def test_rows_are_the_damper(robot, avoidance):
    # A pose with a forearm close to the torso: every pair within d_i gives one row, h = xi (d - d_s)/(d_i - d_s).
    rng = np.random.default_rng(6)
    for q in robot.random_configurations(50, rng):
        ineq = avoidance.rows(q)
        if ineq.rows:
            break
    spec = avoidance.spec
    for r, pd in enumerate(avoidance.close):
        assert pd.distance < spec.influence_distance
        expect = (
            spec.damper_speed * (pd.distance - spec.safety_distance) / (spec.influence_distance - spec.safety_distance)
        )
        assert ineq.h[r] == pytest.approx(expect)
        assert np.allclose(-ineq.G[r], avoidance.distance_jacobian(pd))


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
    pds = avoidance.distances(q, 0.3)
    return pds[0].distance if pds else 0.3


def _drive(robot, avoidance, points, ticks_each, algo="hqp-nullspace"):
    """Closed loop (the solver integrates its own command) through the left-wrist targets; returns commands and the
    smallest clearance of the commanded joints."""
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
                clear = min(clear, _clearance(avoidance, cmd.q))
            k += 1
    return cmds, clear, core


def test_target_inside_the_torso_stops_at_the_safety_distance(robot, avoidance):
    torso = robot.model.getFrameId("torso_link")
    robot.forward(robot.q_rest)
    inside = robot.data.oMf[torso].translation + np.array([0.05, 0.0, 0.15])  # the chest, inside the torso mesh
    cmds, clear, _core = _drive(robot, avoidance, [inside], 1000)
    d_s = robot.profile.collision.safety_distance
    final = _clearance(avoidance, cmds[-1].q)
    assert final == pytest.approx(d_s, abs=0.004)  # stopped at the surface plus the safety distance
    assert clear > 0.0  # never through it
    assert cmds[-1].status == "collision"
    assert "self-collision" in cmds[-1].reason and "left" in cmds[-1].reason


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
    assert _clearance(avoidance, cmd.q) < 0.0
