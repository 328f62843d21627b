"""Seed 004's posture-mimicry CLIK: exact gradient of H, the null-space term, the solver algorithm."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from services.solver.clik_mimicry import ClikMimicry, clik_step, secondary_velocity
from services.solver.core import SolverConfig, SolverCore
from services.solver.registry import make_algorithm
from shared.kinematics import AlignmentTask, Configuration, FrameTask, orientation_delta
from shared.messages import Header, Target, TaskTargets
from shared.robot.profile import upper_arm_frame
from shared.rotations import matrix_to_quat

LINK = "left_shoulder_yaw_link"


def _arm(robot, side="left"):
    return np.array([robot.joint_names.index(n) for n in robot.profile.arms[side].joints])


def _random_q(robot, rng):
    q = robot.q_rest.copy()
    arm = _arm(robot)
    q[arm] = rng.uniform(robot.lower[arm] * 0.6, robot.upper[arm] * 0.6)
    return q


def test_profile_names_the_link_after_the_shoulder_joints(robot17):
    # The link that plays the upper arm follows the three shoulder joints and carries the elbow.
    assert upper_arm_frame(robot17.profile, "left") == LINK
    frame = robot17.model.frames[robot17.model.getFrameId(LINK)]
    assert robot17.model.names[frame.parentJoint] == "left_shoulder_yaw_joint"


def test_delta_is_the_skew_part_of_eq6_and_small_angle_rotation_vector():
    rng = np.random.default_rng(1)
    R_s = pin.exp3(rng.normal(size=3))
    w = np.array([0.01, -0.02, 0.015])
    R_m = pin.exp3(w) @ R_s
    S = R_m @ R_s.T - np.eye(3)
    d = orientation_delta(R_m, R_s)
    np.testing.assert_allclose(d, [S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]] / np.float64(2))
    np.testing.assert_allclose(d, w, atol=1e-5)  # sin(|w|) ~ |w| at 1.5 degrees


def test_alignment_gradient_matches_finite_differences(robot17):
    rng = np.random.default_rng(0)
    conf = Configuration(robot17)
    task = AlignmentTask(LINK)
    for _ in range(5):
        q = _random_q(robot17, rng)
        conf.update(q)
        _p, R = conf.get_frame_pose(LINK)
        task.set_target(pin.exp3(rng.normal(scale=0.8, size=3)) @ R)
        g = task.gradient(conf)
        num = np.zeros_like(g)
        h = 1e-6
        for i in range(len(q)):
            dq = np.zeros_like(q)
            dq[i] = h
            conf.update(q + dq)
            Hp = task.objective(conf)
            conf.update(q - dq)
            Hm = task.objective(conf)
            num[i] = (Hp - Hm) / (2 * h)
        conf.update(q)
        np.testing.assert_allclose(g, num, atol=1e-7)
        assert np.linalg.norm(g) > 1e-2  # a real gradient, not zeros


def test_null_space_term_never_moves_the_end_effector(robot17):
    """(I - J⁺J) q̇₀ is invisible to the wrist: J (I - J⁺J) q̇₀ = 0 to round-off, and integrating only
    that term turns the upper arm while the wrist stays put (drift second order in the step)."""
    rng = np.random.default_rng(2)
    conf = Configuration(robot17)
    task = AlignmentTask(LINK, _arm(robot17)[:3])
    worst = 0.0
    for _ in range(20):
        q = _random_q(robot17, rng)
        conf.update(q)
        J = conf.get_frame_jacobian("left_wrist")
        qd0 = rng.normal(scale=5.0, size=len(q))
        qd = clik_step(J, np.zeros(6), qd0)
        assert np.linalg.norm(qd) > 0.1  # it does move the joints
        worst = max(worst, np.linalg.norm(J @ qd) / np.linalg.norm(qd0))
    assert worst < 1e-12
    # Integrated: the mimicry gradient alone, wrist task at zero velocity. The wrist's drift is the
    # integration's (second order in the step, so it halves when the step halves), not the term's.
    q = _random_q(robot17, rng)

    def run(dt: float, steps: int) -> tuple[float, float, float]:
        conf.update(q)
        p0 = conf.get_frame_pose("left_wrist")[0].copy()
        e0 = conf.get_frame_pose("left_elbow")[0].copy()
        task.set_target(pin.exp3(np.array([0.0, 0.0, 0.6])) @ conf.get_frame_pose(LINK)[1])
        H0 = task.objective(conf)
        for _ in range(steps):
            J = conf.get_frame_jacobian("left_wrist")
            qd = clik_step(J, np.zeros(6), secondary_velocity(conf, [task], 5.0))
            conf.update(conf.q + qd * dt)
        moved = np.linalg.norm(conf.get_frame_pose("left_elbow")[0] - e0)
        drift = np.linalg.norm(conf.get_frame_pose("left_wrist")[0] - p0)
        return moved, drift, task.objective(conf) / H0

    moved, drift, ratio = run(1e-3, 200)
    moved2, drift2, _ = run(5e-4, 400)
    assert ratio < 0.9  # the upper arm turned towards R_m
    assert moved > 5e-3 and abs(moved2 - moved) < 0.05 * moved  # the elbow swivelled by ~1 cm, both times
    assert drift < 0.01 * moved  # the wrist stayed put ...
    assert drift2 < 0.6 * drift  # ... and what it moved is integration error, halving with the step


def test_secondary_level_does_not_change_the_wrist_velocity(robot17):
    """Whatever η, the end-effector task velocity J q̇ is the same (no clamp active)."""
    rng = np.random.default_rng(3)
    conf = Configuration(robot17, _random_q(robot17, rng))
    wrist = FrameTask("left_wrist", 1.0, 1.0, 2.0)
    p, R = conf.get_frame_pose("left_wrist")
    wrist.set_target(p + np.array([0.01, 0.0, -0.01]), pin.exp3(np.array([0.05, 0, 0])) @ R)
    align = AlignmentTask(LINK, _arm(robot17)[:3])
    align.set_target(pin.exp3(np.array([0.3, -0.2, 0.1])) @ conf.get_frame_pose(LINK)[1])
    lim = np.full(robot17.nq, 1e3)
    A = wrist.compute_qp_objective(conf)[0].copy()  # the level-1 rows: (6, n)
    out = {}
    for eta in (0.0, 10.0):
        sol = ClikMimicry(eta=eta).solve(conf, [[wrist], [align]], -lim, lim)
        assert sol.ok and sol.reason == ""  # no clamp acted
        out[eta] = sol.qd
    np.testing.assert_allclose(A @ out[10.0], A @ out[0.0], atol=1e-10)
    assert np.linalg.norm(out[10.0] - out[0.0]) > 1e-2


def test_clik_mimicry_in_the_solver_core_follows_the_operator_upper_arm(robot14):
    """Targets from a robot posture q*, the upper arm of q* as R_m: the solver's elbow converges to q*'s
    while the wrist pose holds; without R_m the elbow stays off (the term does the work)."""
    assert make_algorithm("clik-mimicry").name == "clik-mimicry"
    robot17 = robot14  # arms only: with the waist free, min-norm steps move the shoulders too
    q_star = robot17.q_rest.copy()
    arm = _arm(robot17)
    q_star[arm[:4]] += [0.3, 0.6, 0.9, -0.3]
    poses = robot17.frame_poses(q_star, names=("left_wrist", "right_wrist", "left_elbow", "right_elbow", LINK,
                                                "right_shoulder_yaw_link"))  # fmt: skip
    tg = {n: Target(poses[n][0], matrix_to_quat(poses[n][1]), np.zeros(3), np.zeros(3)) for n in
          ("left_wrist", "right_wrist")}  # fmt: skip
    errs = {}
    for with_ua in (True, False):
        ua = {"left": matrix_to_quat(poses[LINK][1]), "right": matrix_to_quat(poses["right_shoulder_yaw_link"][1])}
        msg = TaskTargets(Header(1, 0.0), tg, upper_arms=ua if with_ua else {})
        core = SolverCore(robot17, SolverConfig(algo="clik-mimicry", smoothing=False, rate=200.0))
        cmd = core.step(msg, None, 0.0)
        for k in range(1, 300):
            cmd = core.step(None, None, k / 200.0)
            assert np.all(cmd.q >= robot17.lower - 1e-12) and np.all(cmd.q <= robot17.upper + 1e-12)
        got = robot17.frame_poses(cmd.q)
        errs[with_ua] = np.linalg.norm(got["left_elbow"][0] - poses["left_elbow"][0])
        assert np.linalg.norm(got["left_wrist"][0] - poses["left_wrist"][0]) < 2e-3
    assert errs[True] < 0.01
    assert errs[False] > 3 * errs[True]
