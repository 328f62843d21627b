"""Target velocities: finite differences of consecutive targets, first-order low-pass.

Mocap positions carry marker/solver jitter that a finite difference amplifies by the
frame rate (30-120 Hz), so the raw difference is smoothed by
``v_f += a * (v_raw - v_f)`` with ``a = dt / (tau + dt)`` (an exponential moving
average with time constant ``tau`` [s], discretised for a variable dt). ``tau = 0``
passes the raw difference through.
"""

from __future__ import annotations

import numpy as np


class LowPassVelocity:
    """Filtered derivative of a (3,) signal sampled at irregular times.

    Args:
        tau: filter time constant [s] (>= 0).
        max_gap: a dt above this [s] restarts the filter (zero velocity) instead of
            differencing across a dropout.
    """

    def __init__(self, tau: float = 0.05, max_gap: float = 0.5):
        if tau < 0 or max_gap <= 0:
            raise ValueError(f"velocity filter needs tau >= 0 and max_gap > 0, got {tau}, {max_gap}")
        self.tau = float(tau)
        self.max_gap = float(max_gap)
        self.v = np.zeros(3)

    def reset(self) -> None:
        """Forget the history: velocity back to zero."""
        self.v = np.zeros(3)

    def update(self, raw_rate: np.ndarray | None, dt: float) -> np.ndarray:
        """Feed one raw rate and return the filtered one, (3,).

        Args:
            raw_rate: (3,) finite difference / dt, or None when there is no previous sample
                (the filter restarts from zero).
            dt: time since the previous sample [s] (> 0); above ``max_gap`` the filter restarts.
        """
        if raw_rate is None or dt > self.max_gap:
            self.reset()
            return self.v.copy()
        a = dt / (self.tau + dt)
        self.v = self.v + a * (np.asarray(raw_rate, dtype=float) - self.v)
        return self.v.copy()
