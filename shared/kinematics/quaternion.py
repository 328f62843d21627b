"""Quaternion kinematics (seed 003 section 1.4; Jackson, Tracy and Manchester, Planning with Attitude).

Quaternions are ``q = [q_s; q_v]`` (4,), scalar first (w, x, y, z: the project's order),
Hamilton product, ``q`` rotates body-frame vectors into the world: ``[0; x_N] = q ⊗ [0; x_B] ⊗ q^+``.

* ``L(q)``, ``R(q)`` (4, 4): ``q1 ⊗ q2 = L(q1) q2 = R(q2) q1``;
* ``H`` (4, 3) = [0; I] lifts a 3-vector to a pure quaternion; ``T`` = diag(1, -I) conjugates;
* kinematics ``q̇ = ½ q ⊗ [0; ω] = ½ L(q) H ω`` with ω (3,) [rad/s] in the BODY frame;
* attitude Jacobian ``G(q) = L(q) H`` (4, 3): ``δq = G(q) φ`` to first order, for the local
  three-parameter error ``φ`` of ``q ⊗ [√(1 - φᵀφ); φ]`` (φ is half the rotation vector);
* chain rule for ``f: H -> R``: gradient ``∇f = ∂f/∂q G(q)`` (3,), Hessian
  ``Gᵀ ∂²f/∂q² G - I (∂f/∂q · q)`` (3, 3); for ``f: H -> H``: ``∇f = Gᵀ(f(q)) ∂f/∂q G(q)`` (3, 3).

  Seed 003 prints the Hessian's second term with a plus sign; the second derivative of
  ``√(1 - φᵀφ)`` at φ = 0 is ``-I``, which gives the minus sign used here (and in Jackson et al.);
  the finite-difference test in tests/kinematics/test_quaternion.py decides between them.
"""

from __future__ import annotations

import numpy as np

from shared.kinematics.poe import skew

#: (4, 3) lift of a 3-vector to a pure quaternion.
H = np.vstack([np.zeros((1, 3)), np.eye(3)])
#: (4, 4) conjugation matrix: q^+ = T q.
T = np.diag([1.0, -1.0, -1.0, -1.0])


def _product_matrix(q: np.ndarray, cross_sign: float) -> np.ndarray:
    """(4, 4) ``[[s, -vᵀ], [v, s I + cross_sign [v]x]]``: L(q) with +1, R(q) with -1.

    The two products differ only in the order of the cross product ``v x p_v``.
    """
    s, v = q[0], q[1:]
    out = np.empty((4, 4))
    out[0, 0] = s
    out[0, 1:] = -v
    out[1:, 0] = v
    out[1:, 1:] = s * np.eye(3) + cross_sign * skew(v)
    return out


def L(q: np.ndarray) -> np.ndarray:
    """(4, 4) left-multiplication matrix: q ⊗ p = L(q) p."""
    return _product_matrix(q, 1.0)


def R(q: np.ndarray) -> np.ndarray:
    """(4, 4) right-multiplication matrix: p ⊗ q = R(q) p."""
    return _product_matrix(q, -1.0)


def qmul(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product q1 ⊗ q2 (4,)."""
    return L(q1) @ q2


def conj(q: np.ndarray) -> np.ndarray:
    """Conjugate q^+ = [q_s; -q_v] (4,)."""
    return T @ q


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a unit quaternion: Hᵀ L(q) R(q)ᵀ H (seed 003's rotation of [0; x])."""
    return H.T @ L(q) @ R(q).T @ H


def rotate(q: np.ndarray, x: np.ndarray) -> np.ndarray:
    """x (3,) rotated by q: the vector part of q ⊗ [0; x] ⊗ q^+."""
    return H.T @ L(q) @ R(q).T @ H @ x


def qdot(q: np.ndarray, omega_body: np.ndarray) -> np.ndarray:
    """q̇ (4,) = ½ L(q) H ω for a body angular velocity ω (3,) [rad/s]."""
    return 0.5 * L(q) @ H @ omega_body


def G(q: np.ndarray) -> np.ndarray:
    """Attitude Jacobian (4, 3) = L(q) H."""
    return L(q) @ H


def from_local(phi: np.ndarray) -> np.ndarray:
    """Unit quaternion [√(1 - φᵀφ); φ] (4,) of a local error φ (3,), |φ| <= 1."""
    return np.r_[np.sqrt(max(0.0, 1.0 - float(phi @ phi))), phi]


def from_axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Unit quaternion [cos(θ/2); sin(θ/2) a] (4,) of a rotation ``angle`` [rad] about ``axis`` (3,)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    return np.r_[np.cos(angle / 2.0), np.sin(angle / 2.0) * a]


def integrate(q: np.ndarray, omega_body: np.ndarray, dt: float) -> np.ndarray:
    """q after a constant body rate ω (3,) [rad/s] for dt [s]: q ⊗ [cos(|ω|dt/2); sin(|ω|dt/2) ω̂]."""
    w = float(np.linalg.norm(omega_body))
    if w * dt < 1e-12:
        return q.copy()
    return qmul(q, from_axis_angle(omega_body, w * dt))


def gradient(dfdq: np.ndarray, q: np.ndarray) -> np.ndarray:
    """∇f (3,) = ∂f/∂q G(q) of f: H -> R, from its Euclidean gradient ∂f/∂q (4,) at q."""
    return dfdq @ G(q)


def hessian(dfdq: np.ndarray, d2fdq2: np.ndarray, q: np.ndarray) -> np.ndarray:
    """∇²f (3, 3) = Gᵀ ∂²f/∂q² G - I (∂f/∂q · q) of f: H -> R at q (see the module docstring on the sign)."""
    Gq = G(q)
    return Gq.T @ d2fdq2 @ Gq - np.eye(3) * float(dfdq @ q)


def jacobian_map(dfdq: np.ndarray, q: np.ndarray, fq: np.ndarray) -> np.ndarray:
    """∇f (3, 3) = Gᵀ(f(q)) ∂f/∂q G(q) of f: H -> H: maps the input error φ to the output's φ'.

    Args:
        dfdq: (4, 4) Euclidean Jacobian of f at q. q: (4,) input. fq: (4,) f(q).
    """
    return G(fq).T @ dfdq @ G(q)
