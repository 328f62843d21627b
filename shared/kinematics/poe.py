"""Product-of-exponentials kinematics (seed 003 section 1.1/1.3; Lynch and Park, Modern Robotics).

Conventions (Modern Robotics): a twist or screw axis is ``V = [ω (3); v (3)]`` — angular part
first. ``T`` (4, 4) is a homogeneous transform [m]. For a chain of n joints:

* space form: ``T(θ) = e^[S1]θ1 ... e^[Sn]θn M``, screw axes ``S_i`` (6,) in the fixed (space)
  frame {s}, ``M`` the end-effector pose in {s} at θ = 0;
* body form: ``T(θ) = M e^[B1]θ1 ... e^[Bn]θn``, ``B_i = Ad_{M^-1} S_i`` in the end-effector
  frame {b} at θ = 0.

Jacobians (6, n) map θ̇ [rad/s] (or [m/s] for prismatic joints) to twists:
``V_s = J_s θ̇`` (space twist: the end-effector body's angular velocity and the velocity of
the body point at the origin of {s}, both in {s} axes); ``V_b = J_b θ̇`` (body twist, in
{b}). The mixed frame B[A] of seed 003 (origin at {b}'s origin, axes of {s}) gives
``[ω; ṗ]`` with ṗ the velocity of the end-effector origin in {s} axes: what one means by
"the hand's velocity" (Pinocchio's LOCAL_WORLD_ALIGNED with its rows swapped).

Everything here is plain numpy (no Pinocchio), so the tests can hold it against Pinocchio
and MuJoCo as independent implementations.
"""

from __future__ import annotations

import math

import numpy as np

#: Below this angle [rad] the exponential and logarithm use their small-angle limits.
SMALL = 1e-9


def skew(w: np.ndarray) -> np.ndarray:
    """(3, 3) matrix [w] with [w] x = w × x, for w (3,)."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def vec_to_se3(V: np.ndarray) -> np.ndarray:
    """(4, 4) se(3) matrix [V] of a twist V = [ω; v] (6,)."""
    out = np.zeros((4, 4))
    out[:3, :3] = skew(V[:3])
    out[:3, 3] = V[3:]
    return out


def se3_to_vec(X: np.ndarray) -> np.ndarray:
    """Twist (6,) [ω; v] of an se(3) matrix (4, 4)."""
    return np.array([X[2, 1], X[0, 2], X[1, 0], X[0, 3], X[1, 3], X[2, 3]])


def trans_inv(T: np.ndarray) -> np.ndarray:
    """Inverse (4, 4) of a homogeneous transform, using R^T."""
    R, p = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ p
    return out


def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint Ad_T = [[R, 0], [[p] R, R]]: maps a twist in frame {b} to {a} for T = T_ab."""
    R, p = T[:3, :3], T[:3, 3]
    out = np.zeros((6, 6))
    out[:3, :3] = R
    out[3:, 3:] = R
    out[3:, :3] = skew(p) @ R
    return out


def ad(V: np.ndarray) -> np.ndarray:
    """(6, 6) Lie bracket matrix ad_V = [[[ω], 0], [[v], [ω]]] of a twist V (6,)."""
    out = np.zeros((6, 6))
    W = skew(V[:3])
    out[:3, :3] = W
    out[3:, 3:] = W
    out[3:, :3] = skew(V[3:])
    return out


def exp3(w_theta: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) e^[ω̂θ] of an exponential coordinate vector ω̂θ (3,) [rad] (Rodrigues)."""
    theta = math.sqrt(float(w_theta @ w_theta))
    if theta < SMALL:
        return np.eye(3) + skew(w_theta)
    W = skew(w_theta / theta)
    return np.eye(3) + math.sin(theta) * W + (1.0 - math.cos(theta)) * (W @ W)


def exp6(V_theta: np.ndarray) -> np.ndarray:
    """Transform (4, 4) e^[S]θ of a twist times its magnitude, S θ (6,) (Modern Robotics eq. 3.88).

    For a unit rotation axis ``ω̂`` and angle θ: ``R = e^[ω̂]θ``,
    ``p = (I θ + (1 - cos θ)[ω̂] + (θ - sin θ)[ω̂]^2) v``; for ω = 0 (prismatic) ``p = v θ``.
    """
    w, v = V_theta[:3], V_theta[3:]
    T = np.eye(4)
    theta = math.sqrt(float(w @ w))
    if theta < SMALL:
        T[:3, 3] = v
        return T
    W = skew(w / theta)
    W2 = W @ W
    T[:3, :3] = np.eye(3) + math.sin(theta) * W + (1.0 - math.cos(theta)) * W2
    G = np.eye(3) * theta + (1.0 - math.cos(theta)) * W + (theta - math.sin(theta)) * W2
    T[:3, 3] = G @ (v / theta)
    return T


def log3(R: np.ndarray) -> np.ndarray:
    """Exponential coordinates ω̂θ (3,) [rad], θ in [0, π], of a rotation (3, 3)."""
    c = (np.trace(R) - 1.0) / 2.0
    c = min(1.0, max(-1.0, c))
    theta = math.acos(c)
    if theta < SMALL:
        return np.zeros(3)
    if math.pi - theta < 1e-6:
        # Near π: the axis from the symmetric part R = 2 ω̂ω̂^T - I (largest diagonal for stability).
        k = int(np.argmax(np.diag(R)))
        w = R[:, k].copy()
        w[k] += 1.0
        w /= math.sqrt(2.0 * (1.0 + R[k, k]))
        return w * theta
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * math.sin(theta))
    return w * theta


def log6(T: np.ndarray) -> np.ndarray:
    """Twist S θ (6,) [ω̂θ; vθ] with e^[Sθ] = T (4, 4) (Modern Robotics algorithm 3.2)."""
    R, p = T[:3, :3], T[:3, 3]
    wt = log3(R)
    theta = math.sqrt(float(wt @ wt))
    if theta < SMALL:
        return np.r_[np.zeros(3), p]
    W = skew(wt / theta)
    Ginv = np.eye(3) / theta - W / 2.0 + (1.0 / theta - 0.5 / math.tan(theta / 2.0)) * (W @ W)
    return np.r_[wt, (Ginv @ p) * theta]


def screw_axis(axis: np.ndarray, point: np.ndarray, pitch: float = 0.0) -> np.ndarray:
    """Screw axis S (6,) of a revolute joint: ``[ŝ; -ŝ × q + h ŝ]`` (seed 003 eq. for S).

    Args:
        axis: joint axis direction ŝ (3,) (normalised here). point: a point q (3,) [m] on the axis.
        pitch: screw pitch h [m/rad] (0 for a revolute joint).
    """
    s = np.asarray(axis, dtype=float)
    s = s / np.linalg.norm(s)
    return np.r_[s, -np.cross(s, point) + pitch * s]


def prismatic_axis(direction: np.ndarray) -> np.ndarray:
    """Screw axis S (6,) = [0; v̂] of a prismatic joint along ``direction`` (3,)."""
    v = np.asarray(direction, dtype=float)
    return np.r_[np.zeros(3), v / np.linalg.norm(v)]


def space_to_body(M: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Body screw axes B (6, n) = Ad_{M^-1} S of space axes S (6, n) for home pose M (4, 4)."""
    return adjoint(trans_inv(M)) @ S


def fk_space(M: np.ndarray, S: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """End-effector pose T (4, 4) = e^[S1]θ1 ... e^[Sn]θn M; S (6, n), θ (n,)."""
    T = np.eye(4)
    for i in range(S.shape[1]):
        T = T @ exp6(S[:, i] * theta[i])
    return T @ M


def fk_body(M: np.ndarray, B: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """End-effector pose T (4, 4) = M e^[B1]θ1 ... e^[Bn]θn; B (6, n), θ (n,)."""
    T = M.copy()
    for i in range(B.shape[1]):
        T = T @ exp6(B[:, i] * theta[i])
    return T


def jacobian_space(S: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Space Jacobian J_s (6, n): column i = Ad_{e^[S1]θ1...e^[S(i-1)]θ(i-1)} S_i (seed 003 §1.3)."""
    J = S.astype(float).copy()
    T = np.eye(4)
    for i in range(1, S.shape[1]):
        T = T @ exp6(S[:, i - 1] * theta[i - 1])
        J[:, i] = adjoint(T) @ S[:, i]
    return J


def jacobian_body(B: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Body Jacobian J_b (6, n): column i = Ad_{e^-[Bn]θn...e^-[B(i+1)]θ(i+1)} B_i."""
    n = B.shape[1]
    J = B.astype(float).copy()
    T = np.eye(4)
    for i in range(n - 2, -1, -1):
        T = T @ exp6(-B[:, i + 1] * theta[i + 1])
        J[:, i] = adjoint(T) @ B[:, i]
    return J


def mixed_from_space(J_s: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Mixed-frame B[A] Jacobian (6, n) from the space one: ``[[I, 0], [-[p], I]] J_s``.

    The space twist's linear part is the velocity of the body point at the space origin; the
    point at the end-effector origin p (3,) [m] moves at ``v + ω × p = v - [p] ω``. (Seed 003
    prints ``[p]`` in that block for the [v; ω] ordering of its reference; with this module's
    [ω; v] ordering and p from {s} to {b} the block is ``-[p]``.)
    Rows: [ω (3) in {s} axes; ṗ (3) in {s} axes].
    """
    out = J_s.copy()
    out[3:] -= skew(p) @ J_s[:3]
    return out


def mixed_from_body(J_b: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Mixed-frame B[A] Jacobian (6, n) from the body one: ``diag(R, R) J_b``, R (3, 3) = R_sb."""
    out = np.empty_like(J_b)
    out[:3] = R @ J_b[:3]
    out[3:] = R @ J_b[3:]
    return out


def jacobian_space_dot(S: np.ndarray, theta: np.ndarray, dtheta: np.ndarray) -> np.ndarray:
    """Time derivative J̇_s (6, n) of the space Jacobian along θ̇ (n,).

    ∂J_si/∂θ_j = ad_{J_sj} J_si for j < i (0 otherwise), so J̇_si = Σ_{j<i} ad_{J_sj θ̇_j} J_si.
    """
    J = jacobian_space(S, theta)
    Jd = np.zeros_like(J)
    acc = np.zeros(6)  # Σ_{j<i} J_sj θ̇_j: the twist of link i-1 in {s}
    for i in range(S.shape[1]):
        Jd[:, i] = ad(acc) @ J[:, i]
        acc = acc + J[:, i] * dtheta[i]
    return Jd


def point_acceleration_bias(S: np.ndarray, M: np.ndarray, theta: np.ndarray, dtheta: np.ndarray) -> np.ndarray:
    """J̇ θ̇ (3,) [m/s^2] of the end-effector origin: its acceleration in {s} when θ̈ = 0.

    With p the origin, ṗ = v_s + ω_s × p, so p̈ = (J̇_s θ̇)_v + (J̇_s θ̇)_ω × p + ω_s × ṗ at θ̈ = 0.
    """
    T = fk_space(M, S, theta)
    p = T[:3, 3]
    J = jacobian_space(S, theta)
    Vs = J @ dtheta
    a = jacobian_space_dot(S, theta, dtheta) @ dtheta
    w, v = Vs[:3], Vs[3:]
    pd = v + np.cross(w, p)
    return a[3:] + np.cross(a[:3], p) + np.cross(w, pd)
