"""A saturated wrist level traded against the lower levels (``SolverConfig.saturation_weight``, h12v).

Why this exists: when the wrists cannot be met within the joint box, the strict hierarchy keeps level 1's
least-squares optimum, whose joints sit at their bounds and leave the elbow level nothing; on the vigorous clips
the elbows drifted 8-11 cm off. The trade gives up a capped share of the wrist residual for the lower levels on
those ticks only; ticks whose wrist level can be met stay strict.
"""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import SolverConfig, SolverCore
from services.solver.hqp_nullspace import HqpNullspace
from services.solver.qp import make_backend
from services.solver.saturation import SaturatedWristTrade
from tests.solver.test_core import targets_from_q

# Two joints, box [-1, 1]^2. Level 1 asks x1 + x2 = 2.5 (the box reaches 2: strict optimum x = (1, 1), r1* = 0.5);
# level 2 asks x1 - x2 = 3, which the strict optimum misses by 3. With the wrist weight w the weighted optimum is
# x = (1, t), t = (1.5 w^2 - 2) / (w^2 + 1), r1 = 3.5 / (w^2 + 1): at w = 2, t = 0.8 and r1 = 0.7 = 1.4 r1*.
A1, B1 = np.array([[1.0, 1.0]]), np.array([2.5])
A2, B2 = np.array([[1.0, -1.0]]), np.array([3.0])
LB, UB = -np.ones(2), np.ones(2)


def _strict():
    return HqpNullspace(make_backend("daqp"), eps=1e-12, compiled=False)


def test_the_trade_of_a_two_joint_problem_has_its_known_answer():
    strict = _strict().solve_matrices([A1, A2], [B1, B2], LB, UB)
    np.testing.assert_allclose(strict.qd, [1.0, 1.0], atol=1e-9)
    r1 = strict.residuals[0]
    assert r1 == pytest.approx(0.5)
    trade = SaturatedWristTrade(make_backend("daqp"), weight=2.0, tolerance=0.6, damping=1e-12)
    aim = trade.wrist_velocity(strict_problem := _problem(), strict.qd)
    assert aim is not None and aim == pytest.approx([1.8], abs=1e-6)  # within the cap (0.7 <= 1.6 * 0.5): uncapped
    assert trade.counts == {"traded": 1, "capped": 0}
    # the strict hierarchy on the re-aimed level 1: the same point, level 1 met exactly at the aim
    reaimed = _strict().solve_matrices([A1, A2], [aim, B2], LB, UB)
    np.testing.assert_allclose(reaimed.qd, [1.0, 0.8], atol=1e-6)
    assert np.linalg.norm(A1 @ reaimed.qd - B1) == pytest.approx(0.7, abs=1e-6)
    assert np.linalg.norm(A2 @ reaimed.qd - B2) == pytest.approx(2.8, abs=1e-6)  # the strict optimum: 3
    assert strict_problem.bs[0] is B1  # the problem is not changed


def test_a_trade_that_costs_the_wrists_more_than_the_tolerance_is_capped():
    # tolerance 0.2: r1 <= 0.6. At w = 2 the weighted optimum (1, 0.8) gives up 0.7; the aim moves back along the
    # segment from its wrist velocity 1.8 to the strict optimum's 2.0 to where the residual is the cap: 1.9.
    trade = SaturatedWristTrade(make_backend("daqp"), weight=2.0, tolerance=0.2, damping=1e-12)
    aim = trade.wrist_velocity(_problem(), np.array([1.0, 1.0]))
    assert aim is not None and aim == pytest.approx([1.9], abs=1e-6)
    assert trade.counts == {"traded": 1, "capped": 1}
    # the strict hierarchy meets it: level 1 exactly at the cap, level 2 between the strict and the weighted
    reaimed = _strict().solve_matrices([A1, A2], [aim, B2], LB, UB)
    assert np.linalg.norm(A1 @ reaimed.qd - B1) == pytest.approx(0.6, abs=1e-6)
    assert np.linalg.norm(A2 @ reaimed.qd - B2) == pytest.approx(2.9, abs=1e-6)
    # no tolerance: the strict optimum's own wrist velocity
    strict_only = SaturatedWristTrade(make_backend("daqp"), weight=2.0, tolerance=0.0, damping=1e-12)
    assert strict_only.wrist_velocity(_problem(), np.array([1.0, 1.0])) == pytest.approx([2.0], abs=1e-9)


def _problem():
    from services.solver.base import LevelProblem

    return LevelProblem([A1, A2], [B1, B2], LB, UB)


def _tick(robot, cfg: SolverConfig, targets):
    core = SolverCore(robot, cfg)
    core.reset(robot.q_rest)
    return core, core.step(targets, None, 0.0)


def test_the_solver_trades_only_on_ticks_whose_wrists_cannot_be_met(robot17):
    robot = robot17
    # Saturated: the wrists where they are but moving at 5 m/s (from rest the box gives them well under that), the
    # elbows where they are and still: the strict optimum moves the elbows with the wrists, whatever it costs them.
    fast = targets_from_q(robot, robot.q_rest, vel=np.array([0.0, 0.0, 5.0]))
    for e in ("left_elbow", "right_elbow"):
        fast.targets[e].v[:] = 0.0
    strict_core, strict = _tick(robot, SolverConfig(qp="daqp", saturation_weight=0.0), fast)
    assert strict_core.saturation is None  # 0 turns it off: the strict hierarchy on every tick
    r1, r2 = strict.residuals[:2]
    # At weight 2 and at the shipped 4 the elbow level, which the strict optimum left nothing, gets a share for a
    # wrist residual within the cap (the wrists give 5e-6 of 6.79 m/s, the elbows gain 2.5e-5 of 0.660; 1.608
    # against 1.687 at weight 2 before session 18, when the wrist orientations' rows, gain 30 and cost 0.3, made
    # most of level 2's residual here and the shoulder links were not guarded).
    for cfg in (SolverConfig(qp="daqp", saturation_weight=2.0), SolverConfig(qp="daqp")):
        traded_core, traded = _tick(robot, cfg, fast)
        assert strict.status == traded.status == "infeasible"
        assert traded.residuals[0] <= (1.0 + cfg.saturation_tolerance) * r1 + 1e-9  # the wrists lose at most that
        assert traded.residuals[0] > r1 + 1e-6  # ... and do give something up
        assert traded.residuals[1] < r2 - 1e-5  # ... for the elbows
        assert traded_core.saturation.counts["traded"] == 1
    # Met: the same targets at rest, 0.1 mm off: the wrists are met and the solution is the strict one, bit for bit.
    near = targets_from_q(robot, robot.q_rest, offset=np.array([0.0, 0.0, 1e-4]))
    _, strict = _tick(robot, SolverConfig(qp="daqp", saturation_weight=0.0), near)
    core, traded = _tick(robot, SolverConfig(qp="daqp"), near)
    assert strict.status == traded.status == "ok"
    np.testing.assert_array_equal(traded.q, strict.q)
    assert core.saturation.counts["traded"] == 0


def test_the_feedforward_trigger_trades_an_outrun_arm_not_a_lagging_one(robot17):
    """``saturation_trigger``: a still target 10 cm from the wrists (the start-up move from rest: gain x error is
    far beyond the box) misses the strict wrist level, yet the operator is not outrunning the arm, so the
    "feedforward" trigger keeps the strict solution bit for bit while "residual" (the default) trades it; a target
    moving at 5 m/s is out of the joints' speed reach and is traded by both."""
    robot = robot17
    lagging = targets_from_q(robot, robot.q_rest, offset=np.array([0.0, 0.0, 0.1]))
    _, strict = _tick(robot, SolverConfig(qp="daqp", saturation_weight=0.0), lagging)
    assert strict.status == "infeasible"
    ff_cfg = SolverConfig(qp="daqp", saturation_weight=2.0, saturation_trigger="feedforward")
    ff_core, ff = _tick(robot, ff_cfg, lagging)
    np.testing.assert_array_equal(ff.q, strict.q)
    assert ff_core.saturation.counts["traded"] == 0
    res_core, res = _tick(robot, SolverConfig(qp="daqp", saturation_weight=2.0), lagging)
    assert res_core.config.saturation_trigger == "residual"  # the default trigger
    assert res_core.saturation.counts["traded"] == 1
    assert not np.array_equal(res.q, strict.q)
    fast = targets_from_q(robot, robot.q_rest, vel=np.array([0.0, 0.0, 5.0]))
    for trigger in ("feedforward", "residual"):
        core, _ = _tick(robot, SolverConfig(qp="daqp", saturation_weight=2.0, saturation_trigger=trigger), fast)
        assert core.saturation.counts["traded"] == 1, trigger
    with pytest.raises(ValueError, match="saturation_trigger"):
        SolverConfig(saturation_trigger="always")


def test_the_trade_is_for_strict_hierarchies_without_a_reserve_and_its_settings_are_checked(robot17):
    assert SolverCore(robot17, SolverConfig(algo="wqp", saturation_weight=2.0)).saturation is None
    assert SolverCore(robot17, SolverConfig(algo="hqp-original", saturation_weight=2.0)).saturation is not None
    assert SolverCore(robot17, SolverConfig(saturation_weight=2.0, level1_reserve=0.2)).saturation is None
    with pytest.raises(ValueError, match="saturation"):
        SolverConfig(saturation_weight=-1.0)
    with pytest.raises(ValueError, match="saturation"):
        SaturatedWristTrade(make_backend("daqp"), weight=0.0, tolerance=0.6)
