"""Numpy inference of the posture policy: file format, hash, block-diagonal network, gate."""

from __future__ import annotations

import numpy as np
import pytest

from services.posture.features import decoder_input, virtual_target
from services.posture.policy import PolicyError, PosturePolicy, _layers, mlp, save_policy
from shared.robot.pinocchio_model import build_robot_model
from shared.targets import SIDES
from tests.posture.policy_files import policy_meta, random_weights, write_random_policy


@pytest.fixture(scope="module")
def robot14():
    return build_robot_model(with_waist=False)


def test_round_trip_and_fused_network_equals_each_arm(tmp_path, robot14):
    path = write_random_policy(tmp_path / "p.npz", robot14, threshold=0.05)
    pol = PosturePolicy.load(path)
    rng = np.random.default_rng(1)
    weights = random_weights(np.random.default_rng(0))
    for _ in range(5):
        S = rng.normal(size=(2, 14))
        out = pol.act(S)
        for i, s in enumerate(SIDES):
            a = mlp(_layers(weights, f"{s}.enc"), S[i])
            z = mlp(_layers(weights, f"{s}.dec"), decoder_input(a, S[i]))
            np.testing.assert_allclose(out.qd0[i], a, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(out.x_dv[i], virtual_target(pol.arms[i], z), atol=1e-12)
            gap = np.linalg.norm(out.x_dv[i] - S[i, 4:7])
            assert out.gap[i] == pytest.approx(gap)
            assert out.gate[i] == (gap <= 0.05)


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


def test_non_finite_state_closes_the_gate(tmp_path, robot14):
    pol = PosturePolicy.load(write_random_policy(tmp_path / "p.npz", robot14, threshold=1e3))
    S = np.zeros((2, 14))
    S[:, 0] = 1.0
    assert pol.act(S).gate.all()
    S[1, 8] = np.nan
    out = pol.act(S)
    # NaN travels through the fused product (0 * NaN = NaN) into both arms: both gates close.
    assert not out.gate.any()
