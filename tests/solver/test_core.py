"""SolverCore in closed loop on the real G1 kinematics (Pinocchio): limits, start-up, holds, failures."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.solver.core import SolverConfig, SolverCore
from services.solver.qp import DaqpBackend, QpResult
from shared.messages import Header, Target, TaskTargets

DT = 0.002


def quat_wxyz(R: np.ndarray) -> np.ndarray:
    q = pin.Quaternion(R)
    return np.array([q.w, q.x, q.y, q.z])


def targets_from_q(robot, q, seq=0, stamp=0.0, valid=True, offset=None, vel=None) -> TaskTargets:
    offset = np.zeros(3) if offset is None else offset
    vel = np.zeros(3) if vel is None else vel
    poses = robot.frame_poses(q)
    return TaskTargets(
        Header(seq, stamp),
        {
            n: Target(poses[n][0] + offset, quat_wxyz(poses[n][1]), vel.copy(), np.zeros(3), valid)
            for n in ("left_wrist", "right_wrist", "left_elbow", "right_elbow")
        },
    )


def assert_safe(robot, cmd, q_prev):
    assert np.all(np.isfinite(cmd.q)) and np.all(np.isfinite(cmd.qd))
    assert np.all(cmd.q >= robot.lower - 1e-12) and np.all(cmd.q <= robot.upper + 1e-12)
    assert np.all(np.abs(cmd.qd) <= robot.vmax + 1e-9)
    assert np.all(np.abs(cmd.q - q_prev) <= robot.vmax * DT + 1e-9)


ALGOS = [
    ("hqp-nullspace", "piqp"),
    ("hqp-nullspace", "daqp"),
    ("hqp-original", "daqp"),
    ("wqp", "piqp"),
    ("clik-nullspace", "piqp"),
    ("dls", "piqp"),
]


@pytest.mark.parametrize(("algo", "qp"), ALGOS)
@pytest.mark.parametrize("smoothing", [True, False], ids=["smooth", "raw"])
def test_closed_loop_never_leaves_limits_with_unreachable_and_jumping_targets(robot17, algo, qp, smoothing):
    robot = robot17
    core = SolverCore(robot, SolverConfig(algo=algo, qp=qp, smoothing=smoothing))
    rng = np.random.default_rng(5)
    poses = robot.random_configurations(4, rng)
    q_prev = robot.q_rest.copy()
    statuses = set()
    for k in range(240):
        msg = None
        if k % 5 == 0:
            phase = (k // 60) % 4
            if phase == 3:
                # Unreachable: everything 2 m away.
                msg = targets_from_q(robot, poses[0], k, k * DT, offset=np.array([2.0, 0.0, 0.0]))
            else:
                # Jumps between random poses every 60 ticks.
                msg = targets_from_q(robot, poses[phase], k, k * DT)
        cmd = core.step(msg, None, k * DT)
        assert cmd.status != "failed", cmd.reason
        assert_safe(robot, cmd, q_prev)
        q_prev = cmd.q
        statuses.add(cmd.status)
    assert "infeasible" in statuses  # the unreachable phase is reported
    assert core.counts["safety_clamps"] == 0  # the algorithm itself respected the bounds


def moving_targets(robot, q_of_t, t, k, elbow_offset=None) -> TaskTargets:
    """Targets by forward kinematics with velocities from central differences of the motion."""
    elbow_offset = np.zeros(3) if elbow_offset is None else elbow_offset
    h = 1e-4
    now, ahead, behind = (
        robot.frame_poses(q_of_t(t)),
        robot.frame_poses(q_of_t(t + h)),
        robot.frame_poses(q_of_t(t - h)),
    )
    out = {}
    for n in ("left_wrist", "right_wrist", "left_elbow", "right_elbow"):
        v = (ahead[n][0] - behind[n][0]) / (2 * h)
        w = pin.log3(ahead[n][1] @ behind[n][1].T) / (2 * h)
        off = elbow_offset if "elbow" in n else np.zeros(3)
        out[n] = Target(now[n][0] + off, quat_wxyz(now[n][1]), v, w)
    return TaskTargets(Header(k, t), out)


def test_hqp_nullspace_keeps_wrists_on_target_when_elbows_conflict_and_wqp_does_not(robot14):
    robot = robot14
    rng = np.random.default_rng(11)
    amp = 0.4 * rng.uniform(-1, 1, robot.nq)

    def q_of_t(t):
        return robot.clip(robot.q_rest + amp * np.sin(2.0 * t))

    errs = {}
    for algo in ("hqp-nullspace", "wqp"):
        core = SolverCore(robot, SolverConfig(algo=algo, qp="daqp"))
        worst = 0.0
        for k in range(500):
            t = k * DT
            # Elbow targets 8 cm off: they cannot be met together with the wrists.
            msg = moving_targets(robot, q_of_t, t, k, np.array([0.0, 0.0, 0.08])) if k % 5 == 0 else None
            cmd = core.step(msg, None, t)
            if k > 250:
                p = robot.frame_poses(cmd.q)["left_wrist"][0]
                worst = max(worst, float(np.linalg.norm(p - robot.frame_poses(q_of_t(t))["left_wrist"][0])))
        errs[algo] = worst
    assert errs["hqp-nullspace"] < 2e-3  # [m]
    assert errs["wqp"] > 2.0 * errs["hqp-nullspace"]


@pytest.mark.parametrize("robot_fixture", ["robot17", "robot14"])
def test_start_mid_stream_from_measured_state_without_jump(request, robot_fixture):
    robot = request.getfixturevalue(robot_fixture)
    rng = np.random.default_rng(3)
    q_meas = robot.random_configurations(1, rng)[0]
    core = SolverCore(robot, SolverConfig())
    target_q = robot.random_configurations(1, rng)[0]
    cmd = core.step(targets_from_q(robot, target_q), q_meas, 10.0)
    assert np.all(np.abs(cmd.q - q_meas) <= robot.vmax * DT + 1e-9)
    assert cmd.status in ("ok", "infeasible", "collision")  # a random pose may sit in the body


def test_holds_start_pose_until_targets_arrive(robot17):
    core = SolverCore(robot17, SolverConfig())
    q_meas = robot17.q_rest + 0.1
    for k in range(5):
        cmd = core.step(None, q_meas if k == 0 else None, k * DT)
        assert cmd.status == "init"
        np.testing.assert_allclose(cmd.q, robot17.clip(q_meas))
        np.testing.assert_array_equal(cmd.qd, 0.0)


def test_invalid_and_stale_targets_are_held(robot17):
    robot = robot17
    core = SolverCore(robot, SolverConfig(target_timeout=0.1))
    q_goal = robot.q_rest + 0.05
    core.step(targets_from_q(robot, q_goal, 0, 0.0), None, 0.0)
    bad = targets_from_q(robot, q_goal, 1, 0.01, valid=False, offset=np.array([0.5, 0, 0]))
    cmd = core.step(bad, None, DT)
    assert cmd.status == "held"
    sample = core.tracker.sample("left_wrist", DT)
    np.testing.assert_allclose(sample.p, robot.frame_poses(q_goal)["left_wrist"][0])  # not the invalid one
    for k in range(2, 200):
        cmd = core.step(None, None, k * DT)
    assert cmd.status == "held"  # no message for 0.4 s > timeout
    # Held targets are still tracked: the wrist converged to the last valid target.
    p = robot.frame_poses(cmd.q)["left_wrist"][0]
    assert np.linalg.norm(p - robot.frame_poses(q_goal)["left_wrist"][0]) < 1e-3


def test_target_velocity_is_fed_forward_between_frames(robot17):
    robot = robot17
    core = SolverCore(robot, SolverConfig(target_horizon=0.05))
    v = np.array([0.0, 0.1, 0.0])
    core.step(targets_from_q(robot, robot.q_rest, 0, 0.0, vel=v), None, 0.0)
    s = core.tracker.sample("left_elbow", 0.02)
    np.testing.assert_allclose(s.p, robot.frame_poses(robot.q_rest)["left_elbow"][0] + v * 0.02)
    np.testing.assert_allclose(s.v, v)
    s = core.tracker.sample("left_elbow", 0.2)  # beyond the horizon: frozen, at rest
    np.testing.assert_allclose(s.p, robot.frame_poses(robot.q_rest)["left_elbow"][0] + v * 0.05)
    np.testing.assert_array_equal(s.v, 0.0)


def test_target_samples_are_shared_within_a_tick_and_renewed_by_a_message(robot17):
    """A tick samples each target once (the posture level and the tasks share it); a message at the same time,
    or a later time, gives a new sample."""
    from services.solver.targets import TargetTracker

    robot = robot17
    tracker = TargetTracker(horizon=0.05)
    v = np.array([0.0, 0.1, 0.0])
    tracker.update(targets_from_q(robot, robot.q_rest, 0, 0.0, vel=v), 0.0)
    s = tracker.sample("left_wrist", 0.01)
    assert tracker.sample("left_wrist", 0.01) is s
    p0 = robot.frame_poses(robot.q_rest)["left_wrist"][0]
    np.testing.assert_allclose(tracker.sample("left_wrist", 0.02).p, p0 + 0.02 * v)
    tracker.update(targets_from_q(robot, robot.q_rest, 1, 0.02, offset=np.array([0.1, 0, 0])), 0.02)
    np.testing.assert_allclose(tracker.sample("left_wrist", 0.02).p, p0 + np.array([0.1, 0, 0]))
    # An invalid target at the same time freezes where the extrapolation had got to (not the memo's old sample).
    tracker.update(targets_from_q(robot, robot.q_rest, 2, 0.03, vel=v), 0.03)
    tracker.sample("left_wrist", 0.04)
    tracker.update(targets_from_q(robot, robot.q_rest, 3, 0.04, valid=False), 0.04)
    held = tracker.sample("left_wrist", 0.04)
    assert held.held
    np.testing.assert_allclose(held.p, p0 + 0.01 * v)
    np.testing.assert_array_equal(held.v, 0.0)


class _FailingBackend(DaqpBackend):
    """Fault injection: the QP solver reports failure on every call."""

    def solve(self, *args, **kwargs):
        res = super().solve(*args, **kwargs)
        return QpResult(res.x * np.nan, False, res.iters, "injected failure")


def test_failed_solve_brakes_within_the_limits(robot17):
    robot = robot17
    core = SolverCore(robot, SolverConfig(algo="hqp-nullspace", qp="daqp", smoothing=False))
    for k in range(20):
        cmd = core.step(targets_from_q(robot, robot.q_rest + 0.3, k, k * DT), None, k * DT)
    qd_before = cmd.qd.copy()
    assert np.abs(qd_before).max() > 0.1  # moving when the QP starts failing
    core.algorithm.backend = _FailingBackend()
    core.algorithm.shortcut = False  # force the QP path
    for k in range(20, 60):
        prev = cmd
        cmd = core.step(targets_from_q(robot, robot.q_rest + 0.3, k, k * DT), None, k * DT)
        assert cmd.status == "failed"
        assert "injected failure" in cmd.reason
        # Braking: never faster than before, never more than a_max dt of change per tick.
        assert np.all(np.abs(cmd.qd) <= np.abs(prev.qd) + 1e-12)
        assert np.all(np.abs(cmd.qd - prev.qd) <= robot.amax * DT + 1e-9)
        np.testing.assert_allclose(cmd.q, prev.q + cmd.qd * DT, atol=1e-12)
    np.testing.assert_array_equal(cmd.qd, 0.0)  # stopped
    assert core.counts["failed"] == 40


def test_resync_when_robot_and_command_diverge(robot17):
    robot = robot17
    core = SolverCore(robot, SolverConfig(resync_threshold=0.2, closed_loop=True))
    core.step(targets_from_q(robot, robot.q_rest), None, 0.0)
    far = robot.clip(robot.q_rest + 0.5)
    cmd = core.step(None, far, DT)
    assert core.counts["resyncs"] == 1
    assert np.all(np.abs(cmd.q - far) <= robot.vmax * DT + 1e-9)


def test_command_carries_diagnostics(robot17):
    core = SolverCore(robot17, SolverConfig(algo="hqp-nullspace", qp="piqp", solver_id="shadow"))
    cmd = core.step(targets_from_q(robot17, robot17.q_rest + 0.2), None, 0.0)
    assert cmd.solver_id == "shadow" and cmd.algo == "hqp-nullspace"
    assert len(cmd.residuals) == 3 and all(np.isfinite(cmd.residuals))
    assert cmd.solve_ms > 0
    assert cmd.joints == list(robot17.joint_names)
    decoded = type(cmd).decode(cmd.encode())
    np.testing.assert_allclose(decoded.q, cmd.q)


def test_bad_configuration_is_rejected(robot17):
    with pytest.raises(ValueError, match="unknown algorithm"):
        SolverCore(robot17, SolverConfig(algo="nope"))
    with pytest.raises(ValueError, match="unknown QP backend"):
        SolverCore(robot17, SolverConfig(qp="cvx"))
    with pytest.raises(ValueError, match="rate"):
        SolverConfig(rate=0.0)
    core = SolverCore(robot17, SolverConfig())
    with pytest.raises(ValueError, match="measured q"):
        core.step(None, np.zeros(3), 0.0)


def test_compiled_clip_and_integration_give_the_numpy_steps_bits(robot17):
    """``SolverCore._advance_raw`` through the tick kernel against the numpy steps it replaces
    (``_checked_velocity``, ``_integrate``): the same q_raw, qd_raw, reasons and counts, bit for bit, on
    solutions inside the box, past it (safety clamps), past the position limits, and not finite."""
    from services.solver.base import Solution

    robot = robot17
    fast, ref = SolverCore(robot, SolverConfig()), SolverCore(robot, SolverConfig())
    ref._kernel = None
    assert fast._kernel is not None
    rng = np.random.default_rng(3)
    n = robot.nq
    clamped = stopped = failed = 0
    for k in range(3000):
        q = robot.lower + rng.uniform(-0.01, 1.01, n) * (robot.upper - robot.lower)
        qd0 = rng.uniform(-1.0, 1.0, n) * robot.vmax
        dt = rng.uniform(0.5, 2.0) * DT
        lb, ub = ref.bounds.compute(q, qd0, dt)  # the box a failed solve brakes in (each core its own)
        lb, ub = fast.bounds.compute(q, qd0, dt)
        qd = np.clip(qd0 + rng.uniform(-0.5, 0.5, n) * fast.bounds.amax * dt, lb, ub)
        if k % 3 == 0:  # past the box by up to 1e-8 rad/s on a few joints: a safety clamp or round-off
            qd += rng.uniform(-1e-8, 1e-8, n) * (rng.random(n) < 0.3)
        if k % 97 == 0:
            qd[rng.integers(n)] = np.nan
        results = []
        for core in (fast, ref):
            core.q_raw[:] = q
            core.qd_raw[:] = qd0
            out, reason = core._advance_raw(Solution(qd.copy(), reason="r" if k % 2 else ""), lb, ub, dt)
            results.append((None if out is None else out.copy(), reason, core.q_raw.copy(), core.qd_raw.copy()))
        (a, ra, qa, va), (b, rb, qb, vb) = results
        assert (a is None) == (b is None) and ra == rb
        if a is not None:
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(qa, qb)
        np.testing.assert_array_equal(va, vb)
        failed += a is None
        stopped += a is not None and bool(np.any((q + a * dt < fast.bounds.lower) | (q + a * dt > fast.bounds.upper)))
    assert fast.counts == ref.counts
    clamped = fast.counts["safety_clamps"]
    # Every branch ran: clamped and not, held at a position stop, failed.
    assert 100 < clamped < 1000 and stopped > 100 and failed == 31
