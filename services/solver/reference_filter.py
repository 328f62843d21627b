"""A smooth hand reference from mocap targets: a critically damped second-order filter.

Mocap targets arrive at 30-120 Hz with velocities that jump from frame to frame; sampled at the
planner's 500 Hz (extrapolated, then held), their position is a sawtooth and their velocity a
staircase. Fed straight into seed 002's planner, each step of the staircase is an acceleration
impulse on the hand equality (eq. 8), and since eq. 6 has no posture term and eq. 13 lets the
torso change its acceleration only slowly, torso and arm trade motion in a weakly damped
null-space oscillation. This filter turns the samples into a reference with continuous
position and velocity and bounded acceleration:

    a = clip(ω² (p_in - p) + 2 ω (v_in - v), ±a_max),   v += a Δt,   p += v Δt

(semi-implicit Euler at the planner's tick). Its step response settles without overshoot in
about 6/ω seconds; a ramp fed with its velocity ``v_in`` is followed without lag (without it,
the lag would be 2/ω times the ramp's speed). Measured on real clips
(``python -m services.wbc.clip_replay``): it cuts the torso velocity's share of energy above
2 Hz 7x on a fast reach (guide_active) at the cost of tracking lag; on a two-handed wave
(byebye_happy) it changes little. The planner's limit damper and torso acceleration bound
(:class:`~services.solver.wbqp_accel.WbqpConfig`) are what keep mocap-driven plans bounded.
"""

from __future__ import annotations

import numpy as np


class ReferenceFilter:
    """Critically damped tracking of (p_in, v_in) (3,) samples; outputs p, v, a (3,).

    Args:
        omega: natural frequency ω [rad/s] (> 0).
        acc_max: bound on each component of the output acceleration [m/s^2] (> 0).
    """

    def __init__(self, omega: float, acc_max: float):
        if not omega > 0 or not acc_max > 0:
            raise ValueError(f"reference filter needs omega > 0 and acc_max > 0, got {omega}, {acc_max}")
        self.omega = float(omega)
        self.acc_max = float(acc_max)
        self.p: np.ndarray | None = None
        self.v = np.zeros(3)
        self.a = np.zeros(3)

    def reset(self, p: np.ndarray, v: np.ndarray | None = None) -> None:
        """Start at position p (3,) [m] with velocity v (3,) [m/s] (default rest)."""
        self.p = np.asarray(p, dtype=float).copy()
        self.v = np.zeros(3) if v is None else np.asarray(v, dtype=float).copy()
        self.a = np.zeros(3)

    def step(self, p_in: np.ndarray, v_in: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance by dt [s] towards (p_in, v_in); returns copies of (p, v, a) after the step."""
        if self.p is None:
            self.reset(p_in)
        w = self.omega
        a = w * w * (np.asarray(p_in, dtype=float) - self.p) + 2.0 * w * (np.asarray(v_in, dtype=float) - self.v)
        self.a = np.clip(a, -self.acc_max, self.acc_max)
        self.v = self.v + self.a * dt
        self.p = self.p + self.v * dt
        return self.p.copy(), self.v.copy(), self.a.copy()
