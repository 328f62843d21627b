"""Unsafe targets stay safe (issue 8, item 2).

Unreachable targets, one-metre jumps, fully stretched (singular) arms and targets
inside the torso go to the solver, through :class:`SolverCore` directly and to a
real ``mimic solve`` process on loopback. Every JointCommand must stay within the
joint position limits, |qd| <= vmax and |q_k - q_{k-1}| <= vmax * dt, stay finite,
and the solver must say that it cannot follow (status and residuals).
"""

from __future__ import annotations

import collections
import threading
import time

import numpy as np
import pytest
import zenoh

from services.solver.core import MIN_STEP, SolverConfig, SolverCore
from shared.messages import Header, JointCommand, ServiceStatus, Target, TaskTargets
from shared.robot.pinocchio_model import build_robot_model

TOL = 1e-9  # float round-off only: the limits are hard
N_TICKS = 300
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def _rest_positions(robot) -> dict[str, np.ndarray]:
    return {n: p for n, (p, _R) in robot.frame_poses(robot.q_rest).items()}


def unsafe_cases(robot) -> dict[str, object]:
    """Target sets (pelvis frame [m]) per case; a callable gives the set of tick k."""
    rest = _rest_positions(robot)
    far = np.array([3.0, 0.0, 1.5])
    return {
        # 3 m in front and 1.5 m above the rest pose: no configuration reaches it.
        "unreachable": {n: p + far for n, p in rest.items()},
        # Between the rest pose and 1 m in front of it, switching every 50 ticks.
        "jump_1m": lambda k: {n: p + (np.array([1.0, 0.0, 0.0]) if (k // 50) % 2 else 0.0) for n, p in rest.items()},
        # Sideways along the shoulder line beyond the arm's reach: the arms end fully stretched (singular).
        "stretched": {
            "left_wrist": np.array([0.0, 1.5, 0.35]),
            "right_wrist": np.array([0.0, -1.5, 0.35]),
            "left_elbow": np.array([0.0, 0.9, 0.35]),
            "right_elbow": np.array([0.0, -0.9, 0.35]),
        },
        # Hands and elbows inside the torso, a few cm from the body's mid-plane.
        "inside_torso": {
            "left_wrist": np.array([0.0, 0.02, 0.15]),
            "right_wrist": np.array([0.0, -0.02, 0.15]),
            "left_elbow": np.array([0.0, 0.05, 0.25]),
            "right_elbow": np.array([0.0, -0.05, 0.25]),
        },
    }


def make_targets(seq: int, positions: dict[str, np.ndarray], velocity: float = 0.0) -> TaskTargets:
    """TaskTargets with position-only targets; ``velocity`` [m/s] feeds forward along +x (adversarial)."""
    v = np.array([velocity, 0.0, 0.0])
    return TaskTargets(
        Header(seq, seq * 0.01, time.time_ns()),
        {
            n: Target(np.asarray(p, float), IDENTITY.copy(), v.copy(), np.zeros(3), True, False)
            for n, p in positions.items()
        },
    )


def targets_at(case, k: int) -> dict[str, np.ndarray]:
    return case(k) if callable(case) else case


class SafetyCheck:
    """Accumulates the worst limit violations over a command stream."""

    def __init__(self, robot, dt: float, q0: np.ndarray):
        self.robot, self.dt, self.prev = robot, dt, np.asarray(q0, float).copy()
        self.t_prev: float | None = None  # solver time [s] of the previous command, when known
        self.pos_excess = 0.0  # [rad] beyond lower/upper
        self.vel_ratio = 0.0  # max |qd| / vmax
        self.step_ratio = 0.0  # max |dq| / (vmax dt)
        self.nonfinite = 0
        self.n = 0
        self.big_steps = 0  # steps above vmax*dt (only possible across a message lost on the way)

    def add(self, q: np.ndarray, qd: np.ndarray, t: float | None = None) -> None:
        """One command; ``t`` its solver time [s]: the solver bounds each step by the real time since
        its last tick (at least ``MIN_STEP``), so a late tick may move further than ``vmax * dt``."""
        r = self.robot
        dt = self.dt if t is None or self.t_prev is None else max(t - self.t_prev, MIN_STEP)
        self.t_prev = t
        self.n += 1
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            self.nonfinite += 1
            return
        self.pos_excess = max(self.pos_excess, float(np.max(np.maximum(r.lower - q, q - r.upper))))
        self.vel_ratio = max(self.vel_ratio, float(np.max(np.abs(qd) / r.vmax)))
        ratio = float(np.max(np.abs(q - self.prev) / (r.vmax * dt)))
        self.step_ratio = max(self.step_ratio, ratio)
        self.big_steps += ratio > 1.0 + 1e-6
        self.prev = q.copy()

    def assert_safe(self, what: str, lost: int = 0) -> None:
        """``lost``: commands published but not received (each may double one step)."""
        assert self.n > 0, f"{what}: no commands"
        assert self.nonfinite == 0, f"{what}: {self.nonfinite} non-finite commands"
        assert self.pos_excess <= TOL, f"{what}: joint past its limit by {self.pos_excess:.3g} rad"
        assert self.vel_ratio <= 1.0 + 1e-6, f"{what}: |qd| = {self.vel_ratio:.4f} vmax"
        assert self.big_steps <= lost, f"{what}: {self.big_steps} steps above vmax*dt, {lost} commands lost"
        assert self.step_ratio <= 1.0 + lost + 1e-6, f"{what}: |dq| = {self.step_ratio:.4f} vmax*dt"


# --------------------------------------------------------------------------- SolverCore (quick)


@pytest.mark.parametrize("algo", ["hqp-nullspace", "wqp"])
@pytest.mark.parametrize("case", ["unreachable", "jump_1m", "stretched", "inside_torso"])
def test_solver_core_commands_stay_within_limits(robot, algo, case):
    core = SolverCore(robot, SolverConfig(algo=algo, qp="daqp"))
    core.reset(robot.q_rest)
    spec = unsafe_cases(robot)[case]
    check = SafetyCheck(robot, core.dt, core.q_out)
    statuses: collections.Counter[str] = collections.Counter()
    t = 0.0
    for k in range(N_TICKS):
        # Adversarial velocity feed-forward too: 50 m/s towards the target on the jump ticks.
        vel = 50.0 if case == "jump_1m" and k % 50 == 0 else 0.0
        cmd = core.step(make_targets(k, targets_at(spec, k), vel), None, t)
        t += core.dt
        statuses[cmd.status] += 1
        check.add(cmd.q, cmd.qd)
        if cmd.status in ("infeasible", "held", "failed"):
            # The machine-readable "why": level-1 residual above the tolerance when infeasible.
            assert cmd.residuals, f"{case}: status {cmd.status} without residuals"
            if cmd.status == "infeasible":
                assert cmd.residuals[0] > core.config.infeasible_tol
    check.assert_safe(f"{algo}/{case}")
    # The final clamp guarantees the limits above whatever the algorithm did: it must never have acted.
    assert core.counts["safety_clamps"] == 0, core.counts
    if case in ("unreachable", "stretched"):
        # Never reachable: the solver must not claim it follows. "collision" is infeasible too, with a damper
        # named as the blocker: with the G1's 8 rad/s arms they get far enough within the run for a hand to near
        # the body (4 rad/s did not).
        unmet = statuses["infeasible"] + statuses["collision"]
        assert statuses["ok"] == 0 and unmet > 0.9 * N_TICKS, dict(statuses)
    if case == "jump_1m":
        # The metre jump cannot be followed within vmax: reported as soon as it happens.
        assert statuses["infeasible"] > 0, dict(statuses)


def test_late_ticks_keep_the_limits_without_the_last_clamp(robot):
    """Every tick late (a steady 2-tick step, the longest a tick integrates), through all the unsafe
    cases: the smoother advances in sub-steps of one tick, so it never needs the C2-breaking clamp
    (one long step did: 7 clamps here), and the commands stay within the limits over wall time."""
    core = SolverCore(robot, SolverConfig(algo="hqp-nullspace", qp="daqp"))
    core.reset(robot.q_rest)
    step = 2.0 * core.dt
    check = SafetyCheck(robot, step, core.q_out)
    t, seq = 0.0, 0
    for spec in unsafe_cases(robot).values():
        for k in range(N_TICKS):
            cmd = core.step(make_targets(seq, targets_at(spec, k)), None, t)
            check.add(cmd.q, cmd.qd)
            t += step
            seq += 1
    check.assert_safe("late ticks")
    assert core.counts["safety_clamps"] == 0, core.counts


def test_infeasible_commands_carry_a_reason(robot):
    core = SolverCore(robot, SolverConfig(algo="wqp", qp="daqp"))
    core.reset(robot.q_rest)
    spec = unsafe_cases(robot)["unreachable"]
    cmds = [core.step(make_targets(k, spec), None, k * core.dt) for k in range(50)]
    infeasible = [c for c in cmds if c.status == "infeasible"]
    assert infeasible
    assert all(c.reason for c in infeasible), "infeasible without a reason"


# --------------------------------------------------------------------------- a real `mimic solve`


@pytest.mark.integration
@pytest.mark.slow
def test_real_solver_process_stays_safe_on_unsafe_targets(robot, local_stack):
    """The same cases published over Zenoh to a real ``mimic solve`` process (500 Hz)."""
    keys = local_stack.keys
    local_stack.start_router()
    cmds: list[JointCommand] = []
    status: dict[str, ServiceStatus] = {}
    lock = threading.Lock()

    def on_cmd(s: zenoh.Sample) -> None:
        m = JointCommand.decode(s.payload.to_bytes())
        with lock:
            cmds.append(m)

    z = local_stack.bus
    subs = [
        z.declare_subscriber(keys.command("main"), on_cmd),
        z.declare_subscriber(
            keys.status("solver"),  # instance "main" publishes on the short key
            lambda s: status.__setitem__("solver", ServiceStatus.decode(s.payload.to_bytes())),
        ),
    ]
    # Subscribed before the solver starts: every command it publishes is counted here.
    local_stack.start_all(["solver"])  # the compose command: hqp-nullspace, id main
    pub = z.declare_publisher(keys.targets, express=True)
    cases = unsafe_cases(robot)
    marks: list[tuple[str, int]] = []  # (case, index of the first command after it started)
    seq = 0
    for name, spec in cases.items():
        with lock:
            marks.append((name, len(cmds)))
        for k in range(60):  # 0.6 s per case at 100 Hz
            pub.put(make_targets(seq, targets_at(spec, k * 5)).encode())
            seq += 1
            time.sleep(0.01)
    time.sleep(0.3)
    assert local_stack.running("solver"), "solver died:\n" + local_stack.output()
    # A clean stop publishes a last status: its published count is exact.
    assert local_stack.sup.stop("solver", timeout=10) == 0, local_stack.output()
    time.sleep(0.5)
    for s in subs:
        s.undeclare()
    pub.undeclare()

    dt = 1.0 / 500.0
    assert len(cmds) > 100, f"only {len(cmds)} commands"
    check = SafetyCheck(robot, dt, cmds[0].q)
    for c in cmds:
        check.add(c.q, c.qd, c.t_cmd)
    st = status["solver"]
    lost = st.counts.get("published.commands", 0) - len(cmds)
    assert 0 <= lost <= 0.01 * len(cmds), (lost, st.counts)
    check.assert_safe("mimic solve", lost)
    bounds = [*(i for _n, i in marks), len(cmds)]
    per_case = {}
    for (name, _i), a, b in zip(marks, bounds[:-1], bounds[1:], strict=True):
        per_case[name] = collections.Counter(c.status for c in cmds[a:b])
    # The solver says it cannot follow: on the wire and in its status counts.
    for name in ("unreachable", "stretched"):
        assert per_case[name]["infeasible"] > 0.5 * sum(per_case[name].values()), per_case
    assert st.outcomes.get("infeasible", 0) > 0, st.outcomes
    # The algorithm kept the limits, not the last clamp. A failure names the clamped commands, their case and
    # the solver-time gaps [ticks] before them (a rare one under a full suite's load is not understood yet).
    # (A string message: pytest shortens a tuple's repr and cut the clamped command's line in a failure.)
    assert st.extra.get("safety_clamps") == 0, "\n".join([str(st.extra), *_clamped(cmds, marks, dt)])


def _clamped(cmds: list[JointCommand], marks: list[tuple[str, int]], dt: float) -> list[str]:
    """One line per command whose reason names the safety clamp: index, case, status, reason, and the
    solver-time steps [ticks] of the three commands up to it."""
    out = []
    for i, c in enumerate(cmds):
        if "safety clamp" not in (c.reason or ""):
            continue
        case = next((name for name, start in reversed(marks) if start <= i), "?")
        steps = [round((cmds[j].t_cmd - cmds[j - 1].t_cmd) / dt, 2) for j in range(max(1, i - 2), i + 1)]
        out.append(f"#{i} {case} {c.status}: {c.reason} (steps {steps})")
    return out
