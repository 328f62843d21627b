"""Safety at any rate (issue 13): velocity and acceleration limits hold over wall-clock time.

The commands are judged by their own time stamps (``t_cmd``): |dq/dt| <= vmax and
|d(qd)/dt| <= a_max between consecutive commands, |qd| <= vmax, positions in their
limits, and the last-resort clamp (which would break C2) never acts.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_core import targets_from_q

from services.solver.core import MIN_STEP, SolverConfig, SolverCore
from services.solver.node import TickClock
from shared.robot.pinocchio_model import build_robot_model
from tests.support.profiles import g1_with_motor_acceleration_limits

TOL = 1e-9


@pytest.fixture(scope="module", params=["global", "motor"])
def robot(request, tmp_path_factory):
    """The shipped G1 (one global a_max) and the G1 with its per-joint motor limits (3.2-830 rad/s^2)."""
    if request.param == "global":
        return build_robot_model()
    robot = build_robot_model(g1_with_motor_acceleration_limits(tmp_path_factory.mktemp("profile")))
    assert np.ptp(robot.amax) > 100.0  # the per-joint limits differ: each joint is judged by its own
    return robot


class WallClockCheck:
    """Worst ratios of the command stream against the limits, per wall-clock interval."""

    def __init__(self, robot):
        self.robot = robot
        self.prev = None
        self.v_ratio = 0.0  # max |dq/dt| / vmax
        self.a_ratio = 0.0  # max |d(qd)/dt| / amax
        self.a_joint = np.zeros(robot.nq)  # per joint: max |d(qd)/dt| / its amax
        self.qd_ratio = 0.0  # max |qd| / vmax
        self.pos_excess = 0.0

    def add(self, cmd) -> None:
        r = self.robot
        self.qd_ratio = max(self.qd_ratio, float(np.max(np.abs(cmd.qd) / r.vmax)))
        self.pos_excess = max(self.pos_excess, float(np.max(np.maximum(r.lower - cmd.q, cmd.q - r.upper))))
        if self.prev is not None:
            dt = cmd.t_cmd - self.prev.t_cmd
            self.v_ratio = max(self.v_ratio, float(np.max(np.abs(cmd.q - self.prev.q) / (r.vmax * dt))))
            np.maximum(self.a_joint, np.abs(cmd.qd - self.prev.qd) / (r.amax * dt), out=self.a_joint)
            self.a_ratio = float(np.max(self.a_joint))
        self.prev = cmd

    def assert_safe(self, what: str) -> None:
        assert self.pos_excess <= TOL, f"{what}: joint past its limit by {self.pos_excess:.3g} rad"
        assert self.qd_ratio <= 1.0 + TOL, f"{what}: |qd| = {self.qd_ratio:.4f} vmax"
        assert self.v_ratio <= 1.0 + 1e-6, f"{what}: |dq/dt| = {self.v_ratio:.4f} vmax over wall-clock time"
        assert self.a_ratio <= 1.0 + 1e-6, f"{what}: |dqd/dt| = {self.a_ratio:.4f} a_max over wall-clock time"


def jumping_targets(robot, k: int, poses: np.ndarray, period: int):
    """Targets that jump between random reachable poses every ``period`` ticks (2 m out of reach in phase 3)."""
    phase = (k // period) % 4
    if phase == 3:
        return targets_from_q(robot, poses[0], k, k * 1e-3, offset=np.array([2.0, 0.0, 0.0]))
    return targets_from_q(robot, poses[phase], k, k * 1e-3)


@pytest.mark.parametrize("smoothing", [True, False], ids=["smooth", "raw"])
@pytest.mark.parametrize("algo", ["hqp-nullspace", "wqp", "dls"])
def test_event_ticks_at_1khz_keep_vmax_and_amax_over_wall_clock_time(robot, algo, smoothing):
    """--trigger event at --rate 500: a tick on every target arrival, 1 ms apart (half the nominal dt)."""
    core = SolverCore(robot, SolverConfig(algo=algo, qp="daqp", rate=500.0, smoothing=smoothing))
    poses = robot.random_configurations(3, np.random.default_rng(4))
    check = WallClockCheck(robot)
    fastest = 0.0
    for k in range(800):
        cmd = core.step(jumping_targets(robot, k, poses, 200), None, k * 1e-3)
        check.add(cmd)
        fastest = max(fastest, float(np.max(np.abs(cmd.qd) / robot.vmax)))
    check.assert_safe(f"{algo} event 1 kHz")
    assert fastest > 0.8  # the jumps drove joints near their top speed: the limits were tested
    # ... and the task-driven joint with the lowest a_max used most of it (its own limit bound it, not
    # another's). Slow joints (the waist under the motor limits) are not driven by the tasks: a pull to rest.
    driven = np.setdiff1d(np.arange(robot.nq), core.slow.idx)
    assert check.a_joint[driven[np.argmin(robot.amax[driven])]] > 0.5
    assert core.counts["safety_clamps"] == 0


def test_stall_and_resume_does_not_burst(robot):
    """Ticks at 2 ms, a 200 ms stall, then the rate loop's back-to-back catch-up ticks (0.2 ms apart)."""
    core = SolverCore(robot, SolverConfig(qp="daqp"))
    poses = robot.random_configurations(3, np.random.default_rng(6))
    check = WallClockCheck(robot)
    t = 0.0
    times = []
    for k in range(400):
        if k == 150:
            t += 0.2  # stall
        elif 150 < k <= 175:
            t += 2e-4  # catch-up burst
        else:
            t += 2e-3
        times.append(t)
        cmd = core.step(jumping_targets(robot, k, poses, 100), None, t)
        check.add(cmd)
        if k == 150:
            # The tick after the stall moves as if at most MAX_STEP_TICKS nominal ticks passed.
            assert core.last_step == pytest.approx(2 * core.dt)
    check.assert_safe("stall and resume")
    assert core.counts["safety_clamps"] == 0


def test_steps_closer_than_min_step_move_by_at_most_min_step(robot):
    core = SolverCore(robot, SolverConfig(qp="daqp", smoothing=False))
    q_far = robot.random_configurations(1, np.random.default_rng(1))[0]
    core.step(targets_from_q(robot, q_far, 0, 0.0), None, 0.0)
    for k in range(1, 200):  # get moving
        core.step(None, None, k * 2e-3)
    q0 = core.q_out.copy()
    t = 199 * 2e-3
    for _ in range(10):  # ten ticks at one instant
        core.step(None, None, t)
        assert core.last_step == MIN_STEP
    assert np.all(np.abs(core.q_out - q0) <= robot.vmax * 10 * MIN_STEP + TOL)


def test_blocked_arm_is_not_commanded_far_from_where_it_is(robot):
    """The measured joints stay put (the arm is blocked) while the targets move away: the command stays
    within max_command_lead of them (plus what braking at a_max adds), and within every limit."""
    lead = 0.15
    core = SolverCore(robot, SolverConfig(qp="daqp", max_command_lead=lead))
    q_blocked = robot.q_rest.copy()
    q_goal = robot.clip(robot.q_rest + 0.8)
    check = WallClockCheck(robot)
    worst = 0.0
    for k in range(1000):
        t = k * 2e-3
        cmd = core.step(targets_from_q(robot, q_goal, k, t) if k % 5 == 0 else None, q_blocked, t)
        check.add(cmd)
        worst = max(worst, float(np.max(np.abs(cmd.q - q_blocked))))
    check.assert_safe("blocked arm")
    # Braking overshoot: the command arrives at the window edge at most at the braking speed.
    assert lead * 0.9 < worst <= lead + 0.01
    # Without the window the same command runs off to the targets.
    free = SolverCore(robot, SolverConfig(qp="daqp", max_command_lead=None))
    for k in range(1000):
        t = k * 2e-3
        cmd = free.step(targets_from_q(robot, q_goal, k, t) if k % 5 == 0 else None, q_blocked, t)
    assert np.max(np.abs(cmd.q - q_blocked)) > 3 * lead


def test_stale_measured_joints_no_longer_bound_the_command(robot):
    core = SolverCore(robot, SolverConfig(qp="daqp", max_command_lead=0.15, measured_timeout=0.1))
    q_goal = robot.clip(robot.q_rest + 0.8)
    for k in range(1000):
        t = k * 2e-3
        measured = robot.q_rest if k == 0 else None  # one state, then the sim goes quiet
        cmd = core.step(targets_from_q(robot, q_goal, k, t) if k % 5 == 0 else None, measured, t)
    assert np.max(np.abs(cmd.q - robot.q_rest)) > 0.3


def test_rate_clock_skips_missed_deadlines_instead_of_catching_up():
    clock = TickClock(0.002, event=False)
    t0 = clock.next_t
    clock.ticked(t0 + 0.1)  # this tick came 100 ms late
    assert clock.next_t == pytest.approx(t0 + 0.102)
    assert clock.overruns == 1
    clock.ticked(clock.next_t)
    assert clock.next_t == pytest.approx(t0 + 0.104)
    assert clock.overruns == 1
