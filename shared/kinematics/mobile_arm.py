"""Seed 002 section 3: the hand of a yaw-pitch-pitch arm on a moving torso, in the 7-D coordinates.

Generalised coordinates ``q = [x_b, y_b, z_b, α, θ_a0, θ_a1, θ_a2]`` (7,): torso-centre
position in Σw [m], torso heading α [rad] about the world z (pitch and roll taken as 0, as the
seed does), and the arm's J1 (yaw), J2, J3 (pitch) angles [rad]. The hand is the origin of Σa.

* eq. 1: ``p_w^h = p_w^b + R_z(α) p_b^h(θ)``, with ``p_b^h`` from the arm's PoE chain in Σb;
* eq. 2-3: ``ṗ_w^h = J_a(q) q̇``, J_a (3, 7);
* eq. 9's ``J̇_a q̇`` (3,): the hand's acceleration when q̈ = 0 (analytic, from the PoE
  Jacobian derivative), so ``p̈_w^h = J_a q̈ + J̇_a q̇``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shared.kinematics.poe import fk_space, jacobian_space, jacobian_space_dot, mixed_from_space, skew
from shared.rotations import cross3

NQ = 7
#: Indices into q.
BASE_XY = slice(0, 2)
BASE = slice(0, 4)
ARM = slice(4, 7)
ALPHA = 3
Z = 2


def rot_z(alpha: float) -> np.ndarray:
    """(3, 3) rotation about z by alpha [rad] (seed 002's R_b^w with pitch and roll 0)."""
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class MobileArmKinematics:
    """The hand of a 3-joint arm carried by a torso that moves in x, y, z and yaw.

    Args:
        S: (6, 3) space screw axes of the arm joints in Σb ([ω; v], Modern Robotics order).
        M: (4, 4) pose of Σa in Σb with the arm at 0 (the held wrist joints folded in).
    """

    S: np.ndarray
    M: np.ndarray

    def __post_init__(self) -> None:
        self._joint = []
        for i in range(self.S.shape[1]):
            w, v = self.S[:3, i].astype(float), self.S[3:, i].astype(float)
            if abs(np.linalg.norm(w) - 1.0) > 1e-12:
                raise ValueError(f"arm joint {i}: screw axis needs a unit rotation axis (revolute joint)")
            K = skew(w)
            K2 = K @ K
            self._joint.append((w, v, K, K2, K @ v, K2 @ v))

    def hand_in_torso(self, theta: np.ndarray) -> np.ndarray:
        """p_b^h (3,) [m]: the hand in Σb."""
        return fk_space(self.M, self.S, theta)[:3, 3]

    def hand(self, q: np.ndarray) -> np.ndarray:
        """p_w^h (3,) [m] (eq. 1)."""
        return q[:3] + rot_z(q[ALPHA]) @ self.hand_in_torso(q[ARM])

    def arm_jacobian(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(p_b^h (3,) [m], J (3, 3) [m/rad]): the hand and its linear Jacobian in Σb."""
        p = self.hand_in_torso(theta)
        Jm = mixed_from_space(jacobian_space(self.S, theta), p)
        return p, Jm[3:]

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """J_a (3, 7) [m/m, m/rad]: ṗ_w^h = J_a q̇ (eqs. 2-3)."""
        Rz = rot_z(q[ALPHA])
        p, Jarm = self.arm_jacobian(q[ARM])
        J = np.zeros((3, NQ))
        J[:, :3] = np.eye(3)
        r = Rz @ p
        J[:, ALPHA] = (-r[1], r[0], 0.0)  # e_z × R_z p
        J[:, ARM] = Rz @ Jarm
        return J

    def jacobian_dot_qdot(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """J̇_a q̇ (3,) [m/s^2]: the hand's acceleration in Σw at q̈ = 0 (the term of eq. 9).

        ``p_w^h = p_b + R_z(α) p``: its second derivative at q̈ = 0 is
        ``α̇² (e_z × (e_z × R_z p)) + 2 α̇ e_z × (R_z ṗ) + R_z p̈``, with ṗ = J_arm θ̇ and p̈ the arm's
        own bias ``J̇_arm θ̇`` (space-Jacobian derivative, :func:`jacobian_space_dot`).
        """
        theta, dtheta = q[ARM], qd[ARM]
        ad = qd[ALPHA]
        Rz = rot_z(q[ALPHA])
        Js = jacobian_space(self.S, theta)
        p = self.hand_in_torso(theta)
        Vs = Js @ dtheta
        w, v = Vs[:3], Vs[3:]
        pd = v + np.cross(w, p)
        a = jacobian_space_dot(self.S, theta, dtheta) @ dtheta
        pdd = a[3:] + np.cross(a[:3], p) + np.cross(w, pd)
        ez = np.array([0.0, 0.0, 1.0])
        r = Rz @ p
        return ad * ad * np.cross(ez, np.cross(ez, r)) + 2.0 * ad * np.cross(ez, Rz @ pd) + Rz @ pdd

    def evaluate(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(p_w^h (3,), J_a (3, 7), J̇_a q̇ (3,)) in one pass over the chain (the planner's per-tick call).

        Same quantities as :meth:`hand`, :meth:`jacobian` and :meth:`jacobian_dot_qdot` (the
        tests hold them equal), with each joint exponential computed once.
        """
        theta, dtheta = q[ARM], qd[ARM]
        n = self.S.shape[1]
        Js = np.empty((6, n))
        # Revolute chain with precomputed [ω̂], [ω̂]^2 (see __post_init__): T_i = T_(i-1) e^[S_i]θ_i
        # as (R, p), and J_si = Ad_T(i-1) S_i = [R ω_i; R v_i + p × R ω_i].
        R = np.eye(3)
        pos = np.zeros(3)
        for i in range(n):
            w, v, K, K2, Kv, K2v = self._joint[i]
            Rw = R @ w
            Js[:3, i] = Rw
            Js[3:, i] = R @ v + cross3(pos, Rw)
            th = float(theta[i])
            st, ct = math.sin(th), math.cos(th)
            pos = pos + R @ (v * th + (1.0 - ct) * Kv + (th - st) * K2v)
            R = R @ (np.eye(3) + st * K + (1.0 - ct) * K2)
        p = R @ self.M[:3, 3] + pos
        # J̇_s θ̇ = Σ_i ad(V_{i-1}) J_si θ̇_i, V_{i-1} = Σ_{j<i} J_sj θ̇_j (ad written out: no 6x6 products).
        wacc = np.zeros(3)
        vacc = np.zeros(3)
        aw = np.zeros(3)
        av = np.zeros(3)
        for i in range(n):
            wi, vi, di = Js[:3, i], Js[3:, i], dtheta[i]
            aw += cross3(wacc, wi) * di
            av += (cross3(vacc, wi) + cross3(wacc, vi)) * di
            wacc += wi * di
            vacc += vi * di
        pd = vacc + cross3(wacc, p)
        pdd = av + cross3(aw, p) + cross3(wacc, pd)
        Jarm = np.empty((3, n))
        for i in range(n):
            Jarm[:, i] = Js[3:, i] + cross3(Js[:3, i], p)  # v + ω × p
        Rz = rot_z(q[ALPHA])
        r = Rz @ p
        J = np.zeros((3, NQ))
        J[0, 0] = J[1, 1] = J[2, 2] = 1.0
        J[0, ALPHA], J[1, ALPHA] = -r[1], r[0]
        J[:, ARM] = Rz @ Jarm
        al = qd[ALPHA]
        rpd = Rz @ pd
        # α̇² e_z × (e_z × r) + 2 α̇ e_z × (R_z ṗ) + R_z p̈, with e_z × u = (-u_y, u_x, 0).
        jdqd = Rz @ pdd
        jdqd[0] += -al * al * r[0] - 2.0 * al * rpd[1]
        jdqd[1] += -al * al * r[1] + 2.0 * al * rpd[0]
        return q[:3] + r, J, jdqd
