"""The solver under the G1's motor acceleration limits: slow joints kept out of the tasks, the level-1 reserve.

Why these exist (h12a): with ``motor_acceleration_limits = true`` (waist 3.2-39 rad/s^2, arms 44-830) the waist
was a variable of the wrist level, sat at its acceleration bound on nearly every tick and swung end to end; the
wrist level was infeasible on every tick of a gesture clip and took all the freedom the elbows needed.
"""

from __future__ import annotations

import numpy as np
import pytest

from services.evaluation.runner import run_algorithm
from services.solver.core import (
    MOTOR_LIMITS_RESERVE,
    MOTOR_LIMITS_TASK_ACCELERATION,
    TASK_ACCELERATION,
    SolverConfig,
    SolverCore,
)
from services.solver.slow_joints import ACCEL_SHARE, SlowJoints
from shared.robot.pinocchio_model import build_robot_model
from tests.solver.test_core import targets_from_q
from tests.support.lockstep import clip_targets_until
from tests.support.profiles import g1_with_motor_acceleration_limits

DT = 0.002
WAVE = "dataset-2_wave-right-hand_normal_001.bvh"
UNTIL = 4.0  # [s] of clip: enough for the old solver's elbow to be 15+ cm off (the test's cost)


@pytest.fixture(scope="module")
def motor_robot(tmp_path_factory):
    return build_robot_model(g1_with_motor_acceleration_limits(tmp_path_factory.mktemp("profile")))


def test_slow_joints_are_the_waist_with_motor_limits_and_none_without(motor_robot, robot17):
    core = SolverCore(motor_robot, SolverConfig())
    assert {motor_robot.joint_names[i] for i in core.slow.idx} == set(motor_robot.profile.waist)
    # with a slow joint, the defaults follow what the arms can do: a braking curve at 10 m/s^2, a level-1 reserve
    assert (core.task_acceleration, core._reserve) == (MOTOR_LIMITS_TASK_ACCELERATION, MOTOR_LIMITS_RESERVE)
    # the global 1000 rad/s^2 cap of the shipped profile: no joint is slow, the levels and demands are today's
    shipped = SolverCore(robot17, SolverConfig())
    assert shipped.slow.idx.size == 0
    assert (shipped.task_acceleration, shipped._reserve) == (TASK_ACCELERATION, 0.0)
    off = SolverCore(motor_robot, SolverConfig(slow_joint_acceleration=0.0))
    assert off.slow.idx.size == 0 and off.task_acceleration == TASK_ACCELERATION
    # explicit values win; the reserve is for the strict hierarchies only
    assert SolverCore(robot17, SolverConfig(task_acceleration=7.0, level1_reserve=0.3))._reserve == 0.3
    assert SolverCore(motor_robot, SolverConfig(algo="wqp"))._reserve == 0.0


def test_a_slow_joint_is_pulled_to_rest_within_its_own_box():
    amax = np.array([3.2, 200.0])
    a = ACCEL_SHARE * amax[0]
    slow = SlowJoints(amax, np.zeros(2), threshold=40.0, gain=5.0)
    assert slow.idx.tolist() == [0]
    box = (np.array([-4.0, -4.0]), np.array([4.0, 4.0]))
    # near rest, already moving at the pull: the gain's pull (5 1/s x 0.001 rad), braking would allow more
    lb, ub = box[0].copy(), box[1].copy()
    slow.fix(np.array([-0.001, 0.3]), np.array([0.005, 0.0]), lb, ub, amax, DT)
    assert lb[0] == ub[0] == pytest.approx(0.005)
    assert (lb[1], ub[1]) == (-4.0, 4.0)  # a fast joint keeps its box
    # far from rest, at the braking speed: no faster than it can still brake to rest
    lb, ub = box[0].copy(), box[1].copy()
    v_brake = -np.sqrt(2 * a * 0.4)
    slow.fix(np.array([0.4, 0.0]), np.array([v_brake - 0.001, 0.0]), lb, ub, amax, DT)
    assert lb[0] == ub[0] == pytest.approx(v_brake)
    # from rest: speeds up by a dt a step only
    lb, ub = box[0].copy(), box[1].copy()
    slow.fix(np.array([0.4, 0.0]), np.zeros(2), lb, ub, amax, DT)
    assert lb[0] == ub[0] == pytest.approx(-a * DT)
    # the box wins: a band that does not reach the pull keeps the joint at its edge
    lb, ub = np.array([0.10, -4.0]), np.array([0.11, 4.0])
    slow.fix(np.array([0.4, 0.0]), np.zeros(2), lb, ub, amax, DT)
    assert lb[0] == ub[0] == 0.10


def test_the_waist_returns_to_rest_within_its_limits_while_the_arms_meet_the_wrists(motor_robot):
    # The robot starts with the waist turned and leaning, targets where the arms put the wrists with the waist
    # at rest: the waist comes back at most as fast as its 3.2-39 rad/s^2 allow and the arms end on the targets.
    robot = motor_robot
    core = SolverCore(robot, SolverConfig(qp="daqp"))
    waist = core.slow.idx
    q0 = robot.q_rest.copy()
    q0[waist] = (0.2, 0.05, -0.05)
    want = robot.frame_poses(robot.q_rest)
    core.reset(q0)
    qd_prev = np.zeros(robot.nq)
    for k in range(1500):
        cmd = core.step(targets_from_q(robot, robot.q_rest, seq=k, stamp=k * DT), None, k * DT)
        # the published command within each joint's own limits (the waist's 3.2-39 rad/s^2 included)
        assert np.all(np.abs(cmd.qd - qd_prev) <= robot.amax * DT + 1e-9)
        assert np.all(np.abs(cmd.qd) <= robot.vmax + 1e-9)
        assert np.all(cmd.q >= robot.lower - 1e-12) and np.all(cmd.q <= robot.upper + 1e-12)
        qd_prev = cmd.qd
    assert np.all(np.abs(cmd.q[waist]) < 0.01), cmd.q[waist]
    assert cmd.status == "ok", cmd.reason
    poses = robot.frame_poses(cmd.q)
    for w in ("left_wrist", "right_wrist"):
        assert np.linalg.norm(poses[w][0] - want[w][0]) < 1e-3


def test_wave_right_hand_elbows_with_motor_limits(motor_robot):
    """The gesture clip hacc measured at elbow 0.44 -> 17.7 cm with the motor limits: the waist out of the tasks
    and the level-1 reserve bring it back to a few cm (the old solver: 15+ cm over these 4 s, level 1 met on 0 % of
    the ticks, the waist swung 0.5 rad)."""
    targets = clip_targets_until(WAVE, motor_robot, UNTIL, per_arm_draws=True)  # the targets hacc measured on
    err = {}
    for name, solver in {
        "shipped": {},
        # the solver of the time: no slow joints, no reserve, strict on every tick (no saturation trade either)
        "waist_in_tasks": {
            "slow_joint_acceleration": 0.0,
            "level1_reserve": 0.0,
            "task_acceleration": 30.0,
            "saturation_weight": 0.0,
        },
    }.items():
        tr = run_algorithm(motor_robot, targets, "hqp-nullspace", qp="daqp", solver=solver, collisions=False)
        el = np.concatenate([np.linalg.norm(tr.ref_p[e] - tr.kin_p[e], axis=1) for e in ("left_elbow", "right_elbow")])
        waist = np.abs(tr.q[:, [motor_robot.joint_names.index(j) for j in motor_robot.profile.waist]])
        err[name] = (100 * float(np.mean(el)), float(waist.max()))
    assert err["waist_in_tasks"][0] > 10.0 and err["waist_in_tasks"][1] > 0.2, err  # the failure, reproduced
    assert err["shipped"][0] < 0.4 * err["waist_in_tasks"][0], err
    assert err["shipped"][1] < 0.01, err  # the waist stays at rest
