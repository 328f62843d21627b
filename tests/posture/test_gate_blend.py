"""The posture level's hand-over between the learned policy and the rest pull when the gate switches.

One level structure in both gate states; the policy's share moves by ``dt / posture_blend_time`` a tick;
the output the gate closed on never reaches the solver; a closed gate ends at the pure rest pull.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from services.solver.core import SolverConfig, SolverCore
from shared.robot.pinocchio_model import build_robot_model
from tests.posture.policy_files import write_random_policy
from tests.solver.test_wrist_only_solver import RATE, wrist_stream

#: ticks [start, end) with the gate forced shut (both arms)
SHUT = (60, 110)


@pytest.fixture(scope="module")
def robot17():
    return build_robot_model()


@pytest.fixture(scope="module")
def elbow_policy(robot17, tmp_path_factory):
    """An elbow-kind policy (gate open) asking for elbows 8 cm out to the side of their rest place."""
    rest = robot17.frame_poses(robot17.q_rest)
    target = {s: rest[f"{s}_elbow"][0] + [0.0, 0.08 if s == "left" else -0.08, 0.0] for s in ("left", "right")}
    return write_random_policy(tmp_path_factory.mktemp("blend") / "elbow.npz", robot17, threshold=1e3, elbow=target)


def run_gated(robot, cfg: SolverConfig, shut=SHUT, shut_action=None, frames: int = 30) -> dict:
    """Step the solver through a wrist-only stream with the gate forced shut on ticks ``shut``.

    shut_action: when given, what the policy outputs while shut (an out-of-distribution answer).
    Returns per tick: q (n,), the level structure (task ids), the left elbow task's velocity demand
    ``v + gain (p - e)`` (3,) [m/s] and its pull ``gain (p - e)``, and the left policy weight.
    """
    core = SolverCore(robot, cfg)
    act = core.policy.act
    tick = [0]

    def forced(S):
        out = act(S)
        if shut[0] <= tick[0] < shut[1]:
            out.gate[:] = False
            if shut_action is not None:
                out.action[:] = shut_action
        return out

    core.policy.act = forced
    left_elbow = next(t for t in core.elbow_tasks if t.frame == "left_elbow")
    rec = {"q": [], "levels": [], "demand": [], "pull": [], "weight": []}
    per_frame = int(RATE / 30.0)
    for msg in wrist_stream(robot, frames):
        for j in range(per_frame):
            cmd = core.step(msg if j == 0 else None, None, tick[0] / RATE)
            levels = core._levels_for(core.wrist_only)
            rec["levels"].append(tuple(tuple(id(t) for t in lv) for lv in levels))
            # this tick's demand: the configuration still holds the tick's start (updated at the next step)
            pull = left_elbow.gain * left_elbow.compute_error(core.configuration)  # towards the task's point
            rec["demand"].append(left_elbow.feedforward() + pull)
            rec["pull"].append(pull)
            rec["weight"].append(core.policy_weight["left"] if hasattr(core, "policy_weight") else None)
            rec["q"].append(cmd.q.copy())
            tick[0] += 1
    return {k: np.array(v) if k != "levels" else v for k, v in rec.items()}


def test_a_gate_switch_never_moves_a_task_to_another_level(robot17, elbow_policy):
    cfg = SolverConfig(qp="daqp", rate=RATE, smoothing=False, self_collision=False, posture_policy=str(elbow_policy))
    rec = run_gated(robot17, cfg)
    # One structure whatever the gate says (it used to drop the elbow task and add a rest-pull level).
    assert len(set(rec["levels"])) == 1
    for q in rec["q"]:
        assert np.all(q >= robot17.lower - 1e-12) and np.all(q <= robot17.upper + 1e-12)


def test_a_gate_switch_blends_the_elbow_demand(robot17, elbow_policy):
    cfg = SolverConfig(qp="daqp", rate=RATE, smoothing=False, self_collision=False, posture_policy=str(elbow_policy))
    blend = run_gated(robot17, replace(cfg, posture_blend_time=0.1))
    instant = run_gated(robot17, replace(cfg, posture_blend_time=0.0))
    assert len(set(blend["levels"])) == 1 and len(set(instant["levels"])) == 1
    # The policy's share follows 3u^2 - 2u^3 of a clock u that runs down by dt / T a tick from the
    # closing and up again from the reopening.
    n = round(0.1 * RATE)
    w = blend["weight"]
    down = 1.0 - np.arange(1, n + 1) / n
    np.testing.assert_allclose(w[SHUT[0] : SHUT[0] + n], down * down * (3 - 2 * down), atol=1e-12)
    assert np.all(w[SHUT[0] + n : SHUT[1]] == 0.0) and np.all(w[: SHUT[0]] == 1.0)
    np.testing.assert_allclose(w[SHUT[1] : SHUT[1] + n], 1.0 - down * down * (3 - 2 * down), atol=1e-12)
    # The blend moves the elbow demand by about dt / T = 1/20 of the instant switch's jump a tick (measured:
    # jumps 7.5 / 7.7 m/s at the closing / reopening, blended steps 0.42 / 0.35 m/s at most).
    for t0 in SHUT:
        jump = np.linalg.norm(instant["demand"][t0] - instant["demand"][t0 - 1])
        steps = np.linalg.norm(np.diff(blend["demand"][t0 - 1 : t0 + n + 1], axis=0), axis=1)
        assert jump > 5.0, jump  # the instant switch: the full gain * distance to the predicted elbow
        assert steps.max() < jump / 8, (t0, steps.max(), jump)


def test_what_the_gate_closed_on_never_reaches_the_solver_and_the_fallback_is_the_rest_pull(robot17, elbow_policy):
    cfg = SolverConfig(qp="daqp", rate=RATE, smoothing=False, self_collision=False, posture_policy=str(elbow_policy))
    shut = (60, 10**9)
    plain = run_gated(robot17, cfg, shut, frames=40)
    # The policy answers nonsense while shut (1 m away, or not a number): the commands are the same to the bit.
    for bad in (1.0, np.nan):
        wild = run_gated(robot17, cfg, shut, shut_action=bad, frames=40)
        np.testing.assert_array_equal(wild["q"], plain["q"])
    n = round(cfg.posture_blend_time * RATE)
    assert np.all(plain["weight"][shut[0] + n - 1 :] == 0.0) and plain["weight"][shut[0] + n - 2] > 0.0
    # With the fade over nothing pulls the elbow towards a point: the task only carries the rest pull's
    # elbow velocity (as with a gate that never opened); before the closing the prediction pulled it.
    assert np.all(plain["pull"][shut[0] + n - 1 :] == 0.0)
    assert np.linalg.norm(plain["pull"][shut[0] - 1]) > 0.1
    never = run_gated(robot17, cfg, (0, 10**9), frames=20)
    assert np.all(never["weight"] == 0.0) and np.all(never["pull"] == 0.0)
    for q in plain["q"]:
        assert np.all(q >= robot17.lower - 1e-12) and np.all(q <= robot17.upper + 1e-12)
