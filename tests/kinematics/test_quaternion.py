"""Seed 003 section 1.4: quaternion kinematics, checked against MuJoCo and finite differences."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shared.kinematics import quaternion as qk


def _unit(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


@pytest.fixture()
def rng():
    return np.random.default_rng(17)


def test_products_and_rotation_match_mujoco(rng):
    for _ in range(50):
        a, b = _unit(rng), _unit(rng)
        ref = np.empty(4)
        mujoco.mju_mulQuat(ref, a, b)
        assert np.abs(qk.L(a) @ b - ref).max() < 1e-14
        assert np.abs(qk.R(b) @ a - ref).max() < 1e-14
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, a)
        assert np.abs(qk.rotation_matrix(a) - R.reshape(3, 3)).max() < 1e-14
        x = rng.normal(size=3)
        assert np.abs(qk.rotate(a, x) - R.reshape(3, 3) @ x).max() < 1e-14
        assert np.abs(qk.qmul(a, qk.conj(a)) - [1, 0, 0, 0]).max() < 1e-14


def test_qdot_is_the_derivative_of_a_body_rate_rotation(rng):
    """q̇ = ½ L(q) H ω against a central difference of MuJoCo's own integration."""
    for _ in range(20):
        q, w = _unit(rng), rng.normal(size=3)
        h = 1e-6
        qp, qm = q.copy(), q.copy()
        mujoco.mju_quatIntegrate(qp, w, h)
        mujoco.mju_quatIntegrate(qm, w, -h)
        assert np.abs(qk.qdot(q, w) - (qp - qm) / (2 * h)).max() < 1e-8
        assert np.abs(qk.integrate(q, w, 0.01) - _mj_integrate(q, w, 0.01)).max() < 1e-14


def _mj_integrate(q, w, dt):
    out = q.copy()
    mujoco.mju_quatIntegrate(out, w, dt)
    return out


def _f(q, a, b):
    """A scalar function of a quaternion: squared distance of the rotated a to b (not invariant to q -> -q)."""
    r = qk.rotate(q, a) - b
    return float(r @ r) + 0.3 * q[0]


def _euclid_grad_hess(f, q, h=1e-5):
    g = np.zeros(4)
    Hs = np.zeros((4, 4))
    E = np.eye(4)
    for i in range(4):
        g[i] = (f(q + h * E[i]) - f(q - h * E[i])) / (2 * h)
        for j in range(4):
            Hs[i, j] = (
                f(q + h * E[i] + h * E[j])
                - f(q + h * E[i] - h * E[j])
                - f(q - h * E[i] + h * E[j])
                + f(q - h * E[i] - h * E[j])
            ) / (4 * h * h)
    return g, Hs


def _local_grad_hess(f, q, h=1e-4):
    """Gradient and Hessian of φ -> f(q ⊗ [√(1-φᵀφ); φ]) at φ = 0 by finite differences."""

    def g(phi):
        return f(qk.qmul(q, qk.from_local(phi)))

    E = np.eye(3)
    grad = np.array([(g(h * E[i]) - g(-h * E[i])) / (2 * h) for i in range(3)])
    hess = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            hess[i, j] = (
                g(h * E[i] + h * E[j]) - g(h * E[i] - h * E[j]) - g(-h * E[i] + h * E[j]) + g(-h * E[i] - h * E[j])
            ) / (4 * h * h)
    return grad, hess


def test_chain_rule_gradient_and_hessian_of_a_scalar_function(rng):
    for _ in range(10):
        q, a, b = _unit(rng), rng.normal(size=3), rng.normal(size=3)

        def f(x, a=a, b=b):
            return _f(x, a, b)

        dfdq, d2f = _euclid_grad_hess(f, q)
        grad_fd, hess_fd = _local_grad_hess(f, q)
        assert np.abs(qk.gradient(dfdq, q) - grad_fd).max() < 1e-6
        hess = qk.hessian(dfdq, d2f, q)
        assert np.abs(hess - hess_fd).max() < 1e-4
        # Seed 003 prints "+ I (∂f/∂q q)": that sign misses the finite differences by 2 ∂f/∂q q.
        seed_sign = qk.G(q).T @ d2f @ qk.G(q) + np.eye(3) * float(dfdq @ q)
        assert np.abs(seed_sign - hess_fd).max() > 100 * np.abs(hess - hess_fd).max()


def test_chain_rule_jacobian_of_a_quaternion_function(rng):
    """f: H -> H, f(q) = a ⊗ q ⊗ q ⊗ b (unit a, b): ∇f = Gᵀ(f(q)) ∂f/∂q G(q) maps φ to φ'."""
    for _ in range(10):
        q, a, b = _unit(rng), _unit(rng), _unit(rng)

        def f(x, a=a, b=b):
            return qk.qmul(qk.qmul(a, qk.qmul(x, x)), b)

        h = 1e-6
        dfdq = np.column_stack([(f(q + h * e) - f(q - h * e)) / (2 * h) for e in np.eye(4)])
        nabla = qk.jacobian_map(dfdq, q, f(q))
        fq = f(q)
        for phi in np.eye(3) * 1e-6:
            out = qk.qmul(qk.conj(fq), f(qk.qmul(q, qk.from_local(phi))))
            assert np.abs(out[1:] - nabla @ phi).max() < 1e-11
