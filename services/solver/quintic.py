"""Quintic smoothing of the joint trajectory between solver outputs (seed 000, section 3).

Every tick a quintic polynomial is fitted from the current smoothed state
(position, velocity, acceleration) to the solver's latest output, extrapolated
over a short horizon T, with zero acceleration at its end; the command is that
polynomial one tick later. Consecutive segments share position, velocity and
acceleration at the junction, so the commanded trajectory is C2 however
abruptly the raw solution changes. With a constant-velocity raw trajectory the
smoother follows it exactly (no lag).
"""

from __future__ import annotations

import numpy as np


def quintic_coefficients(
    p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, v1: np.ndarray, a1: np.ndarray, T: float
) -> tuple[np.ndarray, ...]:
    """Coefficients c0..c5 (each (n,)) of p(s) = sum c_i s^i meeting both end states at s = 0 and s = T [s]."""
    d = p1 - p0
    T2, T3 = T * T, T * T * T
    c3 = (20.0 * d - (8.0 * v1 + 12.0 * v0) * T - (3.0 * a0 - a1) * T2) / (2.0 * T3)
    c4 = (-30.0 * d + (14.0 * v1 + 16.0 * v0) * T + (3.0 * a0 - 2.0 * a1) * T2) / (2.0 * T3 * T)
    c5 = (12.0 * d - 6.0 * (v1 + v0) * T - (a0 - a1) * T2) / (2.0 * T3 * T2)
    return p0, v0, 0.5 * a0, c3, c4, c5


class QuinticSmoother:
    """Receding-horizon quintic filter of a joint trajectory.

    Args:
        n: number of joints.
        dt: tick [s].
        horizon_ticks: segment length T in ticks (>= 2; larger = smoother, slower to react).
    """

    def __init__(self, n: int, dt: float, horizon_ticks: int = 4):
        if horizon_ticks < 2:
            raise ValueError(f"horizon_ticks must be >= 2, got {horizon_ticks}")
        self.dt = dt
        self.T = horizon_ticks * dt
        # State rows: p, v, a (smoothed) and the segment end p1, v1 (a1 = 0).
        self._S = np.zeros((5, n))
        self.p, self.v, self.a = self._S[0], self._S[1], self._S[2]
        # p, v, a at s = dt are linear in (p0, v0, a0, p1, v1): precompute that (3, 5) map once.
        self._K = self._propagator(dt, self.T)

    @staticmethod
    def _propagator(s: float, T: float) -> np.ndarray:
        K = np.zeros((3, 5))
        for j in range(5):
            e = np.zeros((5, 1))
            e[j] = 1.0
            c0, c1, c2, c3, c4, c5 = quintic_coefficients(e[0], e[1], e[2], e[3], e[4], np.zeros(1), T)
            K[0, j] = (c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5)))))[0]
            K[1, j] = (c1 + s * (2.0 * c2 + s * (3.0 * c3 + s * (4.0 * c4 + s * 5.0 * c5))))[0]
            K[2, j] = (2.0 * c2 + s * (6.0 * c3 + s * (12.0 * c4 + s * 20.0 * c5)))[0]
        return K

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Start at rest (or at qd (n,) [rad/s]) at q (n,) [rad]."""
        self.p[:] = q
        self.v[:] = 0.0 if qd is None else qd
        self.a[:] = 0.0

    def step(self, q_raw: np.ndarray, qd_raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance one tick towards the raw solver state q_raw (n,) [rad], qd_raw (n,) [rad/s].

        Returns:
            smoothed (q (n,) [rad], qd (n,) [rad/s]) one tick later (internal buffers; copy to keep).
        """
        S = self._S
        # Aim at where the raw trajectory will be at the end of the horizon if its velocity holds.
        np.multiply(qd_raw, self.T - self.dt, out=S[3])
        S[3] += q_raw
        S[4] = qd_raw
        S[:3] = self._K @ S
        return self.p, self.v

    def clamp(self, q_prev: np.ndarray, lower: np.ndarray, upper: np.ndarray, vmax: np.ndarray) -> int:
        """Keep the smoothed state inside limits: |q - q_prev| <= vmax dt, lower <= q <= upper, |qd| <= vmax.

        Returns:
            number of joints that had to be clamped (0 in normal operation).
        """
        step = vmax * self.dt
        lo = np.maximum(lower, q_prev - step)
        hi = np.minimum(upper, q_prev + step)
        changed = (self.p < lo) | (self.p > hi) | (self.v < -vmax) | (self.v > vmax)
        if not changed.any():
            return 0
        np.minimum(np.maximum(self.p, lo, out=self.p), hi, out=self.p)
        np.minimum(np.maximum(self.v, -vmax, out=self.v), vmax, out=self.v)
        self.a[changed] = 0.0
        return int(np.count_nonzero(changed))
