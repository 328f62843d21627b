"""The planner's scalar hand kinematics (seed 002 eqs. 1-3, 9) against the seed-003 library it restates.

:meth:`MobileArmKinematics.evaluate_scalars` is the per-tick fast path (plain floats, no numpy);
``hand``/``jacobian``/``jacobian_dot_qdot`` are built from the library (``fk_space``,
``jacobian_space``, ``mixed_from_space``, ``jacobian_space_dot``), which test_poe.py holds against
Pinocchio and MuJoCo. Both must agree over random configurations, far outside the joint ranges too.
"""

from __future__ import annotations

import numpy as np
import pytest

from shared.kinematics.mobile_arm import NQ, MobileArmKinematics
from shared.kinematics.poe import exp6, screw_axis
from shared.robot.wheeled import build_wheeled_robot

TOL = 1e-10
N_CONFIGS = 200


@pytest.fixture(scope="module")
def kin():
    return build_wheeled_robot("tita_piper").kin


def _random_state(rng):
    q = np.r_[rng.uniform(-5, 5, 3), rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi, 3)]
    qd = rng.normal(scale=3.0, size=NQ)
    return q, qd


def _agree(kin, rng):
    for _ in range(N_CONFIGS):
        q, qd = _random_state(rng)
        p, J, jdqd = kin.evaluate_scalars(q.tolist(), qd.tolist())
        assert np.abs(np.array(p) - kin.hand(q)).max() <= TOL
        assert np.array(J).shape == (3, NQ)
        assert np.abs(np.array(J) - kin.jacobian(q)).max() <= TOL
        assert np.abs(np.array(jdqd) - kin.jacobian_dot_qdot(q, qd)).max() <= TOL
        # evaluate() is the same as arrays
        pa, Ja, ja = kin.evaluate(q, qd)
        assert np.array_equal(pa, p) and np.array_equal(Ja, J) and np.array_equal(ja, jdqd)


def test_fast_path_agrees_with_the_library_on_the_tita_piper(kin):
    _agree(kin, np.random.default_rng(17))


def test_fast_path_agrees_on_a_general_chain():
    """Skewed axes through arbitrary points and a rotated home pose: nothing TITA-specific is assumed."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        axes = rng.normal(size=(3, 3))
        S = np.column_stack([screw_axis(a / np.linalg.norm(a), rng.normal(size=3)) for a in axes])
        M = exp6(rng.normal(size=6))
        _agree(MobileArmKinematics(S, M), rng)


def test_prismatic_or_non_unit_axes_are_refused():
    S = np.zeros((6, 3))
    S[5] = 1.0  # prismatic along z: the scalar chain is written for revolute joints
    with pytest.raises(ValueError, match="unit rotation axis"):
        MobileArmKinematics(S, np.eye(4))
