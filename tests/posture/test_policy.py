"""Numpy inference of the posture policy: file format, hash, the fast batched path against the reference, gate."""

from __future__ import annotations

import numpy as np
import pytest

from services.posture.features import ACTION_LIMIT, decoder_input, virtual_target
from services.posture.policy import PolicyError, PosturePolicy, _layers, mlp, save_policy
from shared.robot.pinocchio_model import build_robot_model
from shared.targets import SIDES
from tests.posture.policy_files import policy_meta, random_weights, write_random_policy


@pytest.fixture(scope="module")
def robot14():
    return build_robot_model(with_waist=False)


def test_round_trip_and_fast_path_equals_each_arms_network(tmp_path, robot14):
    path = write_random_policy(tmp_path / "p.npz", robot14, threshold=0.05)
    pol = PosturePolicy.load(path)
    rng = np.random.default_rng(1)
    weights = random_weights(np.random.default_rng(0))
    for _ in range(5):
        S = rng.normal(size=(2, 14))
        out = pol.act(S)
        for i, s in enumerate(SIDES):
            a = np.clip(mlp(_layers(weights, f"{s}.enc"), S[i]), -ACTION_LIMIT, ACTION_LIMIT)
            z = mlp(_layers(weights, f"{s}.dec"), decoder_input(a, S[i]))
            # float32 products against the float64 definition
            np.testing.assert_allclose(out.qd0[i], a, atol=1e-6)
            np.testing.assert_allclose(out.x_dv[i], virtual_target(pol.arms[i], z), atol=1e-6)
            gap = np.linalg.norm(out.x_dv[i] - S[i, 4:7])
            assert out.gap[i] == pytest.approx(gap, abs=1e-9)
            assert out.gate[i] == (gap <= 0.05)


@pytest.mark.parametrize("decoder", [(128, 128), (32,)], ids=["dec128x2", "dec32x1"])
@pytest.mark.parametrize("kind", ["velocity", "posture", "elbow", "swivel"])
def test_fast_path_equals_the_reference_forward_pass(tmp_path, robot14, kind, decoder):
    """act (float32, batched, folded) against act_reference (float64, per arm), on networks of the trained
    sizes (the shipped decoder has one hidden layer of 32) and weight magnitude (0.1 ~ 1/sqrt(128): the
    trained files' layers are of that order)."""
    gain = 20.0
    extra = {"posture": {"posture_gain": gain}, "elbow": {"elbow": {s: [0.1, 0.2, 0.0] for s in SIDES}},
             "swivel": {"swivel": {}}}  # fmt: skip
    path = write_random_policy(tmp_path / "p.npz", robot14, threshold=0.3, hidden=128, scale=0.1, decoder=decoder,
                               **extra.get(kind, {}))  # fmt: skip
    pol = PosturePolicy.load(path)
    assert pol.kind == kind
    rng = np.random.default_rng(2)
    opened = 0
    for _ in range(200):
        S = np.zeros((2, 14))
        Q = rng.normal(size=(2, 4))
        S[:, :4] = Q / np.linalg.norm(Q, axis=1, keepdims=True)
        S[:, 4:7] = rng.normal(0.0, 0.2, (2, 3))
        S[:, 7:] = rng.normal(0.0, 0.5, (2, 7))
        fast, ref = pol.act(S), pol.act_reference(S)
        np.testing.assert_allclose(fast.action, ref.action, atol=1e-6)
        np.testing.assert_allclose(fast.x_dv, ref.x_dv, atol=1e-6)
        np.testing.assert_allclose(fast.gap, ref.gap, atol=1e-6)
        np.testing.assert_allclose(fast.elbow, ref.elbow, atol=1e-5)  # swivel: placed from a float32 angle
        # qd0 = K (a - q) for the posture kind: the action's 1e-6 times K
        np.testing.assert_allclose(fast.qd0, ref.qd0, atol=1e-6 * (gain if kind == "posture" else 1.0))
        near = np.abs(ref.gap - pol.threshold) < 1e-5  # the gate may differ only on its threshold
        assert np.array_equal(fast.gate[~near], ref.gate[~near])
        opened += int(ref.gate.sum())
    assert 0 < opened < 400  # both sides of the threshold were exercised
    if kind in ("elbow", "swivel"):
        assert np.all(fast.qd0 == 0.0)
    if kind == "elbow":
        np.testing.assert_allclose(fast.action, [[0.1, 0.2, 0.0]] * 2, atol=1e-6)
        np.testing.assert_allclose(fast.elbow, fast.action, atol=0.0)


def test_altered_or_foreign_files_are_refused_with_a_reason(tmp_path, robot14):
    path = write_random_policy(tmp_path / "p.npz", robot14)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["left.enc.W0"] = arrays["left.enc.W0"] + 1e-9
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(PolicyError, match="sha256"):
        PosturePolicy.load(tmp_path / "bad.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(PolicyError, match="cannot read"):
        PosturePolicy.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "nometa.npz", x=np.zeros(2))
    with pytest.raises(PolicyError, match="metadata"):
        PosturePolicy.load(tmp_path / "nometa.npz")
    w = random_weights(np.random.default_rng(0))
    w["right.enc.W0"] = np.zeros((13, 16))
    save_policy(tmp_path / "shape.npz", w, policy_meta(robot14, 1.0))
    with pytest.raises(PolicyError, match="14 -> 3"):
        PosturePolicy.load(tmp_path / "shape.npz")
    meta = policy_meta(robot14, 1.0)
    del meta["gate_threshold"]
    save_policy(tmp_path / "meta.npz", random_weights(np.random.default_rng(0)), meta)
    with pytest.raises(PolicyError, match="incomplete"):
        PosturePolicy.load(tmp_path / "meta.npz")


# The non-finite state is the input under test: numpy's "invalid value" warning from the products is expected
# (the real-time path does not pay for an errstate context on every tick).
@pytest.mark.filterwarnings("ignore:invalid value encountered in matmul:RuntimeWarning")
def test_non_finite_state_closes_that_arms_gate(tmp_path, robot14):
    pol = PosturePolicy.load(write_random_policy(tmp_path / "p.npz", robot14, threshold=1e3, posture_gain=10.0))
    S = np.zeros((2, 14))
    S[:, 0] = 1.0
    left = pol.act(S)
    assert left.gate.all()
    left_x_dv = left.x_dv[0].copy()
    for bad in (np.nan, np.inf, -np.inf):
        for k in (0, 5, 8):  # quaternion, position, a joint the hand-only encoder does not read
            S2 = S.copy()
            S2[1, k] = bad
            out = pol.act(S2)
            assert out.gate.tolist() == [True, False], (bad, k)
            np.testing.assert_allclose(out.x_dv[0], left_x_dv)  # the other arm is untouched
