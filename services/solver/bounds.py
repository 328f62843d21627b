"""Joint bounds of one solver step: position, velocity and acceleration limits as a box on qd.

Every QP level gets the same box ``lb <= qd <= ub`` (n,) [rad/s] for a step of
``dt`` [s] (the real time since the last step). It intersects, per joint:

* acceleration: ``|qd - qd_prev| <= a_max dt``;
* deceleration-aware position limits: after moving at qd for dt the joint must
  still be able to stop at a_max before its limit, ``qd dt + qd^2 / (2 a_max) <=
  distance``, i.e. ``qd <= a_max (sqrt(dt^2 + 2 distance / a_max) - dt)``: about
  ``sqrt(2 a_max distance)`` far from the limit and ``distance / dt`` (the step
  cannot pass it) next to it. The same braking bound applies to an optional
  window around the measured joints (``window``): the command may not run away
  from a blocked arm by more than the window's half width;
* velocity: ``|qd| <= vmax``.

The terms are intersected in order of precedence (window, acceleration,
position, velocity): where two cross, the later one wins and the box collapses
onto its nearest edge. Velocity and position limits therefore always hold; the
braking bound is consistent from one step to the next for any sequence of dt
(decelerating at a_max keeps it satisfied), so acceleration only gives way after
an outside jump (a reset while moving). A window that moves against the command
(the robot pushed back) gives way to the acceleration limit: the command brakes
at a_max instead of jumping back into it.

General inequality rows (e.g. velocity dampers on distances, ``G qd <= h``) are
not boxes: they would join as extra rows of every level's QP next to this box.
"""

from __future__ import annotations

import numpy as np


class JointBounds:
    """Per-joint velocity box from position, velocity and acceleration limits (buffers reused).

    Args:
        lower, upper: (n,) position limits [rad].
        vmax: (n,) velocity limits [rad/s], > 0.
        amax: (n,) acceleration limits [rad/s^2], > 0.
        compiled: :meth:`compute` in the numba kernel (``tick_kernel.velocity_box``, compiled when built: the
            solver's per-tick box); False (default, no numba loaded) runs the numpy steps, the readable reference
            the kernel is tested against. Both give the same bits.
    """

    def __init__(
        self, lower: np.ndarray, upper: np.ndarray, vmax: np.ndarray, amax: np.ndarray, compiled: bool = False
    ):
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.vmax = np.asarray(vmax, dtype=float)
        self.amax = np.asarray(amax, dtype=float)
        n = self.lower.shape[0]
        for name, x in (("upper", self.upper), ("vmax", self.vmax), ("amax", self.amax)):
            if x.shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {x.shape}")
        if np.any(self.lower > self.upper):
            raise ValueError("position limits: lower must be <= upper")
        if not (np.all(self.vmax > 0) and np.all(self.amax > 0) and np.all(np.isfinite(self.vmax + self.amax))):
            raise ValueError("velocity and acceleration limits must be finite and > 0")
        self._neg_vmax = -self.vmax
        #: (n,) 2 / amax [s^2/rad], the braking bound's factor (also read by the smoother's compiled check)
        self.two_over_a = 2.0 / self.amax
        self.lb = np.empty(n)
        self.ub = np.empty(n)
        self._t = np.empty(n)
        self._t2 = np.empty(n)
        self._d = np.empty((2, n))  # distances to the stop below and above (``brake_both``)
        self._amax_dt = np.empty(n)  # a_max dt of the last dt
        self._amax_dt_for = None
        self._free = np.empty(n)  # distance to a stop beyond which braking allows more than vmax (``braking_free``)
        self._free_for: tuple[float, float] | None = None
        self._kernel = None
        if compiled:
            from services.solver import tick_kernel

            tick_kernel.warm_up()
            self._kernel = tick_kernel

    def compute(
        self,
        q: np.ndarray,
        qd_prev: np.ndarray,
        dt: float,
        window: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(lb, ub) (n,) [rad/s] for a step dt [s] from q (n,) [rad] moving at qd_prev (n,) [rad/s].

        Args:
            window: optional (lo, hi) (n,) [rad], a second position window (e.g. measured q +- lead).

        Returns:
            internal buffers (copy to keep), lb <= ub everywhere.
        """
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        lb, ub, t = self.lb, self.ub, self._t
        if self._kernel is not None:
            w_lo, w_hi = (lb, ub) if window is None else window  # (lb, ub): unread placeholders
            self._kernel.velocity_box(
                q, qd_prev, dt, self.lower, self.upper, self.vmax, self.amax, self.two_over_a, window is not None,
                w_lo, w_hi, lb, ub,
            )  # fmt: skip
            return lb, ub
        if window is not None:
            lo, hi = self.brake_both(q - window[0], window[1] - q, dt)
            lb[:] = lo
            ub[:] = hi
        else:
            lb.fill(-np.inf)
            ub.fill(np.inf)
        if dt != self._amax_dt_for:
            np.multiply(self.amax, dt, out=self._amax_dt)
            self._amax_dt_for = dt
        np.subtract(qd_prev, self._amax_dt, out=t)
        self._intersect(t, np.add(qd_prev, self._amax_dt, out=self._t2))
        d = self._d
        below, above = np.subtract(q, self.lower, out=d[0]), np.subtract(self.upper, q, out=d[1])
        if not self.braking_free(d, dt):
            # Near a stop: the braking bound is tighter than vmax somewhere. Far from every stop it is looser
            # than vmax on both sides, and the velocity clamp below gives exactly the same box without it.
            self._intersect(*self.brake_both(below, above, dt))
        self._intersect(self._neg_vmax, self.vmax)
        return lb, ub

    def braking_free(self, distances: np.ndarray, dt: float, decel: float = 1.0) -> bool:
        """True when every distance (k, n) [rad] to a stop is so large that ``brake`` allows more than vmax there.

        ``brake(d) >= vmax`` exactly when ``d >= vmax dt + vmax^2 / (2 decel a_max)``; the test keeps a 1 % margin
        over that, far above round-off, so a True answer never hides a braking bound tighter than vmax.
        """
        key = (dt, decel)
        if key != self._free_for:
            np.multiply(self.vmax, dt, out=self._free)
            self._free += self.vmax * self.vmax / (2.0 * decel * self.amax)
            self._free *= 1.01
            self._free_for = key
        return bool((distances > self._free).all())

    def brake_both(
        self, below: np.ndarray, above: np.ndarray, dt: float, decel: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(brake(below, dt, neg=True), brake(above, dt))`` (n,) each, in one pass over both sides (views of an
        internal buffer, valid until the next call): the velocity window between a stop ``below`` [rad] under q and
        one ``above`` over it."""
        d = self._d
        if below is not d[0]:
            d[0] = below
        if above is not d[1]:
            d[1] = above
        out = self.brake(d, dt, decel=decel)
        np.negative(out[0], out=out[0])
        return out[0], out[1]

    def brake(self, distance: np.ndarray, dt: float, neg: bool = False, decel: float = 1.0) -> np.ndarray:
        """Fastest qd (n,) [rad/s] towards a stop ``distance`` (n,) [rad] away that can still stop before it
        (distance may also be (k, n): one row per stop).

        A negative distance (already past it) asks to come back in one step. ``neg`` returns the bound
        for a stop below q (the negated speed). ``decel``: the fraction of a_max the braking may use.
        """
        d = np.maximum(distance, 0.0)
        d *= self.two_over_a
        if decel != 1.0:
            d /= decel
        d += dt * dt
        np.sqrt(d, out=d)
        d -= dt
        d *= self.amax
        if decel != 1.0:
            d *= decel
        d += np.minimum(distance, 0.0) / dt
        if neg:
            np.negative(d, out=d)
        return d

    def _intersect(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """[lb, ub] <- its intersection with [lo, hi]; [lo, hi] wins where they are disjoint."""
        lb, ub = self.lb, self.ub
        np.minimum(np.maximum(lb, lo, out=lb), hi, out=lb)
        np.minimum(np.maximum(ub, lo, out=ub), hi, out=ub)
