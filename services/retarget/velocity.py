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

    def __init__(self, tau: float = 0.05, max_gap: float = 0.5, rows: int | None = None):
        if tau < 0 or max_gap <= 0:
            raise ValueError(f"velocity filter needs tau >= 0 and max_gap > 0, got {tau}, {max_gap}")
        self.tau = float(tau)
        self.max_gap = float(max_gap)
        #: the filtered rate: (3,), or (rows, 3) for ``rows`` signals filtered together
        self.v = np.zeros(3 if rows is None else (rows, 3))

    def reset(self) -> None:
        """Forget the history: velocity back to zero."""
        self.v = np.zeros_like(self.v)

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

    def update_rows(self, raw_rate: np.ndarray | None, dt: float | None, fresh: list[bool]) -> np.ndarray:
        """Several signals at once (a filter made with ``rows``): feed the rows where ``fresh`` (rows bools) their
        raw rates ``raw_rate`` (sum(fresh), 3); every other row restarts from zero (no previous sample), and so
        do all of them when dt [s] is None, <= 0 or above ``max_gap``. Returns the filtered (rows, 3)."""
        if dt is None or not 0 < dt <= self.max_gap or raw_rate is None:
            self.reset()
            return self.v.copy()
        a = dt / (self.tau + dt)
        if all(fresh):
            self.v = self.v + a * (np.asarray(raw_rate, dtype=float) - self.v)
            return self.v.copy()
        rows = np.flatnonzero(fresh)
        old = self.v[rows]
        self.v[:] = 0.0
        self.v[rows] = old + a * (np.asarray(raw_rate, dtype=float) - old)
        return self.v.copy()
