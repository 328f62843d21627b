"""Mirrored demonstrations (left <-> right through the sagittal plane) and the posture action kind."""

from __future__ import annotations

import numpy as np
import pytest

from services.posture.features import (
    ACTION_LIMIT,
    mirror_arm_state,
    mirror_state,
    posture_action,
    state,
)
from services.posture.policy import PolicyError, PosturePolicy, _layers, mlp, save_policy
from services.posture.train import Dataset
from shared.mirror import arm_joints, mirror_signs
from shared.robot.pinocchio_model import build_robot_model
from shared.rotations import matrix_to_quat
from tests.posture.policy_files import policy_meta, random_weights, write_random_policy


@pytest.fixture(scope="module")
def robot14():
    return build_robot_model(with_waist=False)


def _arm_state(robot, q, side, Q_ref):
    pose = robot.frame_poses(q)[f"{side}_wrist"]
    return state(matrix_to_quat(pose[1]), pose[0], q[arm_joints(robot, side)], Q_ref)


def test_mirrored_left_state_is_the_right_arms_state_at_the_mirrored_joints(robot14):
    sign = mirror_signs(robot14)
    # Roll and yaw axes flip under the reflection, pitch axes do not: a sign map that is not all +1.
    assert set(sign) == {-1.0, 1.0} and sign[0] == 1.0
    rest = robot14.frame_poses(robot14.q_rest)
    Q_ref = {s: matrix_to_quat(rest[f"{s}_wrist"][1]) for s in ("left", "right")}
    L, R = arm_joints(robot14, "left"), arm_joints(robot14, "right")
    rng = np.random.default_rng(3)
    for _ in range(10):
        q = robot14.q_rest.copy()
        q[L] = rng.uniform(robot14.lower[L], robot14.upper[L]) * 0.7
        q[R] = sign * q[L]
        s_left = _arm_state(robot14, q, "left", Q_ref["left"])
        s_right = _arm_state(robot14, q, "right", Q_ref["right"])
        np.testing.assert_allclose(mirror_state(s_left, sign), s_right, atol=2e-3)
        np.testing.assert_allclose(mirror_state(mirror_state(s_left, sign), sign), s_left, atol=1e-12)
    z = rng.normal(size=(4, 6))
    np.testing.assert_allclose(mirror_arm_state(z)[:, [0, 2, 3, 5]], z[:, [0, 2, 3, 5]])
    np.testing.assert_allclose(mirror_arm_state(z)[:, [1, 4]], -z[:, [1, 4]])


def test_dataset_with_mirror_gives_each_arm_the_other_arms_samples_reflected(robot14):
    sign = mirror_signs(robot14)
    rng = np.random.default_rng(0)
    d = Dataset(*[[rng.normal(size=(n, dim)) for n in (5, 3)] for dim in (14, 3, 6)])
    m = d.with_mirror(sign)
    assert [len(s) for s in m.S] == [8, 8] and len(m) == 2 * len(d)
    np.testing.assert_array_equal(m.S[0][:5], d.S[0])
    np.testing.assert_allclose(m.S[0][5:], mirror_state(d.S[1], sign))
    np.testing.assert_allclose(m.A[1][3:], d.A[0] * sign[:3])
    np.testing.assert_allclose(m.Z[1][3:], mirror_arm_state(d.Z[0]))


def test_posture_kind_turns_the_shoulder_posture_into_a_bounded_pull(tmp_path, robot14):
    pol = PosturePolicy.load(write_random_policy(tmp_path / "p.npz", robot14, posture_gain=10.0))
    w = random_weights(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for _ in range(5):
        S = rng.normal(scale=0.5, size=(2, 14))
        out = pol.act(S)
        for i, side in enumerate(("left", "right")):
            a = mlp(_layers(w, f"{side}.enc"), S[i])
            np.testing.assert_allclose(out.action[i], a, atol=1e-6)  # the posture itself, unclipped (float32)
            qd0 = np.clip(10.0 * (a - S[i, 7:10]), -ACTION_LIMIT, ACTION_LIMIT)
            np.testing.assert_allclose(out.qd0[i], qd0, atol=1e-5)  # K times the action's 1e-6
    # A hand-only encoder (joint inputs' weights zero, as training exports them): at the target posture
    # the pull is zero, 0.05 rad short of it K * 0.05.
    meta = {**policy_meta(robot14, 1e3), "action_kind": "posture", "posture_gain": 10.0}
    hand = dict(w)
    for side in ("left", "right"):
        hand[f"{side}.enc.W0"] = w[f"{side}.enc.W0"].copy()
        hand[f"{side}.enc.W0"][7:] = 0.0
    pol = PosturePolicy.load(save_policy(tmp_path / "hand.npz", hand, meta))
    S = rng.normal(scale=0.5, size=(2, 14))
    a = pol.act(S).action.astype(float)  # (act's outputs are its float32 buffers)
    S[:, 7:10] = a
    np.testing.assert_allclose(pol.act(S).qd0, 0.0, atol=1e-12)
    S[:, 7:10] = a - 0.05
    np.testing.assert_allclose(pol.act(S).qd0, 0.5, atol=1e-9)
    np.testing.assert_allclose(posture_action(a + 1.0, a, 10.0), ACTION_LIMIT)
    meta = {**policy_meta(robot14, 1.0), "action_kind": "posture"}  # no gain: refused
    save_policy(tmp_path / "nogain.npz", w, meta)
    with pytest.raises(PolicyError, match="gain"):
        PosturePolicy.load(tmp_path / "nogain.npz")
    save_policy(tmp_path / "kind.npz", w, {**meta, "action_kind": "torque", "posture_gain": 1.0})
    with pytest.raises(PolicyError, match="action kind"):
        PosturePolicy.load(tmp_path / "kind.npz")
