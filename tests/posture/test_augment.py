"""Rigid-turn augmentation of elbow-kind samples (services/posture/augment.py) and its use in training."""

from __future__ import annotations

import numpy as np
import pytest

from services.posture.augment import scale_reach, turn_arms, yaw_pitch_rotations
from shared.rotations import matrix_to_quat, quat_to_matrix


def test_a_turned_arm_is_the_same_arm_turned_about_the_shoulder():
    rng = np.random.default_rng(3)
    n = 200
    q_rot, R_rot = yaw_pitch_rotations(rng, n, 15.0)
    for q, R in zip(q_rot, R_rot):
        np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-12)  # the two forms are one rotation
        yaw = np.degrees(np.arctan2(-R[0, 1], R[1, 1]))  # R = Rz(yaw) Ry(pitch): row 2 has no yaw
        pitch = np.degrees(np.arcsin(-R[2, 0]))
        assert abs(yaw) <= 15.0 + 1e-9 and abs(pitch) <= 15.0 + 1e-9 and abs(R[2, 1]) < 1e-12
    assert np.degrees(2 * np.arccos(q_rot[:, 0])).max() > 12.0  # the range is used, not a few degrees
    _q, R_yaw = yaw_pitch_rotations(rng, 50, 15.0, max_pitch_deg=0.0)  # yaw only: the vertical stays put
    np.testing.assert_allclose(R_yaw[:, :, 2], np.tile([0.0, 0.0, 1.0], (50, 1)), atol=1e-15)
    assert np.abs(R_yaw[:, 0, 1]).max() > np.sin(np.radians(12.0))
    centre = np.array([0.0, 0.15, 0.25])
    Q = np.array([matrix_to_quat(quat_to_matrix(rng.normal(size=4))) for _ in range(n)])
    p = centre + rng.normal(0.0, 0.3, (n, 3))
    e = centre + rng.normal(0.0, 0.2, (n, 3))
    hand, elbow = turn_arms(np.c_[Q, p], e, centre, q_rot, R_rot)
    # upper arm and forearm keep their lengths; positions and the hand's orientation turn together
    np.testing.assert_allclose(np.linalg.norm(elbow - centre, axis=1), np.linalg.norm(e - centre, axis=1), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(hand[:, 4:] - elbow, axis=1), np.linalg.norm(p - e, axis=1), atol=1e-12)
    for k in range(n):
        np.testing.assert_allclose(hand[k, 4:] - centre, R_rot[k] @ (p[k] - centre), atol=1e-12)
        np.testing.assert_allclose(quat_to_matrix(hand[k, :4]), R_rot[k] @ quat_to_matrix(Q[k]), atol=1e-12)
    assert (np.einsum("ni,ni->n", hand[:, :4], Q) > 0.0).all()  # the sign convention of the inputs is kept


def test_a_longer_or_shorter_reach_keeps_the_elbow_on_the_arm_and_on_its_side():
    rng = np.random.default_rng(4)
    n, centre, upper, fore = 100, np.array([0.0, 0.15, 0.25]), 0.26, 0.24
    # elbows on the circle that reaches each wrist: random directions, distances well inside the reach
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    d = rng.uniform(0.2, 0.42, n)
    side = rng.normal(size=(n, 3))
    side -= np.einsum("ni,ni->n", side, u)[:, None] * u
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    x = (upper**2 - fore**2 + d**2) / (2 * d)
    e = centre + x[:, None] * u + np.sqrt(upper**2 - x**2)[:, None] * side
    hand = np.c_[rng.normal(size=(n, 4)), centre + d[:, None] * u]
    same, e1 = scale_reach(hand, e, centre, upper, fore, np.ones(n))
    np.testing.assert_allclose(e1, e, atol=1e-12)  # scale 1: nothing moves
    np.testing.assert_allclose(same, hand, atol=1e-12)
    scale = rng.uniform(0.9, 1.1, n)
    out, e2 = scale_reach(hand, e, centre, upper, fore, scale)
    np.testing.assert_array_equal(out[:, :4], hand[:, :4])  # the hand's orientation is kept
    np.testing.assert_allclose(out[:, 4:] - centre, (d * scale)[:, None] * u, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(e2 - centre, axis=1), upper, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(e2 - out[:, 4:], axis=1), fore, atol=1e-12)
    off = e2 - centre - np.einsum("ni,ni->n", e2 - centre, u)[:, None] * u
    np.testing.assert_allclose(off / np.linalg.norm(off, axis=1, keepdims=True), side, atol=1e-9)  # same swivel


torch = pytest.importorskip("torch", reason="training needs the optional extra: pip install 'mimic[train]'")


def test_training_on_turned_arms_predicts_turned_gestures(bvh_clips):
    from services.posture.policy import _layers, mlp
    from services.posture.rollout import ArmsModel, RolloutConfig, prepare_clip, rollout
    from services.posture.train import TrainConfig, fit, from_rollouts
    from shared.robot.pinocchio_model import build_robot_model

    robot = build_robot_model(with_waist=False)
    arms = ArmsModel(robot)
    clip = prepare_clip(sorted(bvh_clips, key=lambda p: p.stat().st_size)[0], robot).slice(0, 60)
    roll = rollout(arms, clip, "expert", None, RolloutConfig(settle=0.5, action_kind="elbow"))
    data = from_rollouts([roll]).with_mirror(arms.mirror, "elbow")
    centres = [f.centre for f in arms.frames]
    base = TrainConfig(hidden=16, epochs=60, batch=64, seed=0, hand_only=True)
    with pytest.raises(ValueError, match="shoulder centres"):
        fit(data, TrainConfig(**{**base.__dict__, "augment_deg": 20.0}))
    plain, _ = fit(data, base, frames=arms.frames)
    turned, _ = fit(data, TrainConfig(**{**base.__dict__, "augment_deg": 25.0}), frames=arms.frames)
    # the decoder trains on the original samples alone in both fits, the encoders differ
    assert not np.array_equal(plain["left.enc.W0"], turned["left.enc.W0"])
    # the same gestures done 20° further out (yaw) and 15° higher (pitch): what the plain fit never saw
    err = {"plain": [], "turned": []}
    for i, side in enumerate(("left", "right")):
        n = len(data.S[i])
        sgn = 1.0 if side == "left" else -1.0
        yaw, pitch = np.radians(20.0) * sgn, np.radians(-15.0)
        Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        Ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
        R_rot = np.tile(Rz @ Ry, (n, 1, 1))
        q_rot = np.tile(matrix_to_quat(Rz @ Ry), (n, 1))
        hand, elbow = turn_arms(data.S[i][:, :7], data.A[i], centres[i], q_rot, R_rot)
        S = data.S[i].copy()
        S[:, :7] = hand
        for name, w in (("plain", plain), ("turned", turned)):
            err[name].append(np.linalg.norm(mlp(_layers(w, f"{side}.enc"), S) - elbow, axis=1).mean())
    assert np.mean(err["turned"]) < 0.8 * np.mean(err["plain"]), err
