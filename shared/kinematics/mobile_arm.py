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
        # Per revolute joint, as plain floats for :meth:`evaluate_scalars`: ω, v, the products
        # (ωx², ωy², ωz², ωxωy, ωxωz, ωyωz) of ω ωᵀ = [ω̂]^2 + I, [ω̂]v and [ω̂]^2 v.
        self._joint: list[tuple] = []
        for i in range(self.S.shape[1]):
            w, v = self.S[:3, i].astype(float), self.S[3:, i].astype(float)
            if abs(np.linalg.norm(w) - 1.0) > 1e-12:
                raise ValueError(f"arm joint {i}: screw axis needs a unit rotation axis (revolute joint)")
            K = skew(w)
            wx, wy, wz = w.tolist()
            ww = (wx * wx, wy * wy, wz * wz, wx * wy, wx * wz, wy * wz)
            self._joint.append(
                (tuple(w.tolist()), tuple(v.tolist()), ww, tuple((K @ v).tolist()), tuple((K @ K @ v).tolist()))
            )
        self._home = tuple(np.asarray(self.M, dtype=float)[:3, 3].tolist())

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
        """(p_w^h (3,), J_a (3, 7), J̇_a q̇ (3,)) in one pass over the chain (:meth:`evaluate_scalars` as arrays).

        Same quantities as :meth:`hand`, :meth:`jacobian` and :meth:`jacobian_dot_qdot` (the
        seed-003 library; the tests hold them equal over random configurations).
        """
        p, J, jdqd = self.evaluate_scalars(q.tolist(), qd.tolist())
        return np.array(p), np.array(J), np.array(jdqd)

    def evaluate_scalars(self, q: list[float], qd: list[float]) -> tuple[list[float], list[list[float]], list[float]]:
        """The planner's per-tick call: (p_w^h [3], J_a rows [3][7], J̇_a q̇ [3]) as Python floats.

        q, qd: the 7 coordinates and their rates as sequences of floats. The same arithmetic as
        the library functions (revolute PoE chain, space Jacobian from adjoints, J̇_s θ̇ from
        the Lie brackets), written out for a 3x3 rotation and plain floats: at 7 coordinates,
        numpy's per-call cost (~1 us per small-array operation) is most of the time, not the arithmetic.
        """
        x, y, z, alpha, *theta = q
        al = qd[3]
        dtheta = qd[4:]
        # T_i = T_(i-1) e^[S_i]θ_i as (R row-major 9 floats, pos); J_si = [R ω_i; R v_i + pos × R ω_i].
        r0, r1, r2, r3, r4, r5, r6, r7, r8 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
        px = py = pz = 0.0
        cols = []  # (ωx, ωy, ωz, vx, vy, vz) per joint, in Σb
        for ((wx, wy, wz), (vx, vy, vz), (xx, yy, zz, xy, xz, yz), (kv0, kv1, kv2), (mv0, mv1, mv2)), th in zip(
            self._joint, theta
        ):
            first = not cols  # T_0 = I: the first joint's products are skipped (J_s1 = S_1)
            if first:
                cols.append((wx, wy, wz, vx, vy, vz))
            else:
                ax = r0 * wx + r1 * wy + r2 * wz
                ay = r3 * wx + r4 * wy + r5 * wz
                az = r6 * wx + r7 * wy + r8 * wz
                bx = r0 * vx + r1 * vy + r2 * vz + py * az - pz * ay
                by = r3 * vx + r4 * vy + r5 * vz + pz * ax - px * az
                bz = r6 * vx + r7 * vy + r8 * vz + px * ay - py * ax
                cols.append((ax, ay, az, bx, by, bz))
            st, ct = math.sin(th), math.cos(th)
            oc, ts = 1.0 - ct, th - st
            # translation of e^[S]θ: (I θ + (1 - cos θ)[ω̂] + (θ - sin θ)[ω̂]^2) v
            tx = vx * th + oc * kv0 + ts * mv0
            ty = vy * th + oc * kv1 + ts * mv1
            tz = vz * th + oc * kv2 + ts * mv2
            if first:
                px, py, pz = tx, ty, tz
            else:
                px += r0 * tx + r1 * ty + r2 * tz
                py += r3 * tx + r4 * ty + r5 * tz
                pz += r6 * tx + r7 * ty + r8 * tz
            # rotation of e^[S]θ (Rodrigues, |ω| = 1): cos θ I + sin θ [ω̂] + (1 - cos θ) ω ωᵀ, then R <- R E
            sx, sy, sz = st * wx, st * wy, st * wz
            e0, e4, e8 = ct + oc * xx, ct + oc * yy, ct + oc * zz
            oxy, oxz, oyz = oc * xy, oc * xz, oc * yz
            e1, e3 = oxy - sz, oxy + sz
            e2, e6 = oxz + sy, oxz - sy
            e5, e7 = oyz - sx, oyz + sx
            if first:
                r0, r1, r2, r3, r4, r5, r6, r7, r8 = e0, e1, e2, e3, e4, e5, e6, e7, e8
                continue
            r0, r1, r2, r3, r4, r5, r6, r7, r8 = (
                r0 * e0 + r1 * e3 + r2 * e6,
                r0 * e1 + r1 * e4 + r2 * e7,
                r0 * e2 + r1 * e5 + r2 * e8,
                r3 * e0 + r4 * e3 + r5 * e6,
                r3 * e1 + r4 * e4 + r5 * e7,
                r3 * e2 + r4 * e5 + r5 * e8,
                r6 * e0 + r7 * e3 + r8 * e6,
                r6 * e1 + r7 * e4 + r8 * e7,
                r6 * e2 + r7 * e5 + r8 * e8,
            )
        hx, hy, hz = self._home
        px += r0 * hx + r1 * hy + r2 * hz
        py += r3 * hx + r4 * hy + r5 * hz
        pz += r6 * hx + r7 * hy + r8 * hz
        # J̇_s θ̇ = Σ_i ad(V_(i-1)) J_si θ̇_i with V_(i-1) = Σ_(j<i) J_sj θ̇_j; (W, U) = V_(i-1), (aw, av) the sum.
        Wx = Wy = Wz = Ux = Uy = Uz = 0.0
        awx = awy = awz = avx = avy = avz = 0.0
        arm = []  # columns of the arm's linear Jacobian at the hand: v_i + ω_i × p
        for (ax, ay, az, bx, by, bz), d in zip(cols, dtheta):
            awx += (Wy * az - Wz * ay) * d
            awy += (Wz * ax - Wx * az) * d
            awz += (Wx * ay - Wy * ax) * d
            avx += (Uy * az - Uz * ay + Wy * bz - Wz * by) * d
            avy += (Uz * ax - Ux * az + Wz * bx - Wx * bz) * d
            avz += (Ux * ay - Uy * ax + Wx * by - Wy * bx) * d
            Wx += ax * d
            Wy += ay * d
            Wz += az * d
            Ux += bx * d
            Uy += by * d
            Uz += bz * d
            arm.append((bx + ay * pz - az * py, by + az * px - ax * pz, bz + ax * py - ay * px))
        # ṗ = v + ω × p; p̈ = a_v + a_ω × p + ω × ṗ (hand in Σb at q̈ = 0).
        dx = Ux + Wy * pz - Wz * py
        dy = Uy + Wz * px - Wx * pz
        dz = Uz + Wx * py - Wy * px
        ddx = avx + awy * pz - awz * py + Wy * dz - Wz * dy
        ddy = avy + awz * px - awx * pz + Wz * dx - Wx * dz
        ddz = avz + awx * py - awy * px + Wx * dy - Wy * dx
        c, s = math.cos(alpha), math.sin(alpha)
        rx, ry = c * px - s * py, s * px + c * py  # R_z p
        row_x = [1.0, 0.0, 0.0, -ry]
        row_y = [0.0, 1.0, 0.0, rx]
        row_z = [0.0, 0.0, 1.0, 0.0]
        for jx, jy, jz in arm:
            row_x.append(c * jx - s * jy)
            row_y.append(s * jx + c * jy)
            row_z.append(jz)
        # α̇² e_z × (e_z × r) + 2 α̇ e_z × (R_z ṗ) + R_z p̈, with e_z × u = (-u_y, u_x, 0).
        vx, vy = c * dx - s * dy, s * dx + c * dy
        jdqd = [
            c * ddx - s * ddy - al * al * rx - 2.0 * al * vy,
            s * ddx + c * ddy - al * al * ry + 2.0 * al * vx,
            ddz,
        ]
        return [x + rx, y + ry, z + pz], [row_x, row_y, row_z], jdqd
