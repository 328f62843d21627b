"""The smoother's per-tick limit check compiled with numba: ``QuinticSmoother``'s numpy rows, one call.

Why compiled: every tick the limiter builds six limited quantities of the next state and their bounds
(step-dependent velocity and acceleration steps, the braking bound before each stop) and tests them, about
25 numpy calls on 17-element vectors: a microsecond of call overhead each for a few hundred flops. Here one
loop over the joints does it. Each element goes through the numpy path's operations in the same order, so
the rows, the bounds and the verdict are the same bits (``tests/solver/test_quintic.py`` holds it to
``QuinticSmoother(compiled=False)``). Only the check is here: a tick with a joint out of its limits still
takes the numpy path's line search (a few ticks in a hundred on violent input, none on most gestures).

Compilation: ``cache=True`` as ``hqp_kernel``; :func:`warm_up` compiles or loads it before the first tick.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_warm = False


@njit(cache=True)
def _brake(distance: float, dt: float, amax: float, two_over_a: float, decel: float) -> float:
    """``JointBounds.brake`` of one joint: the fastest speed towards a stop ``distance`` away, step by step."""
    d = max(distance, 0.0)
    d *= two_over_a
    if decel != 1.0:
        d /= decel
    d += dt * dt
    d = math.sqrt(d)
    d -= dt
    d *= amax
    if decel != 1.0:
        d *= decel
    return d + min(distance, 0.0) / dt


@njit(cache=True)
def limit_rows(y, p0, v0, s, lower, upper, vmax, amax, two_over_a, decel, lo, hi, bad):
    """Fill the limited quantities of the next state and their bounds; flag the joints out of them.

    Args:
        y: (6, n) rows p, v, a of the next state given, rows dp, dv and the half-step-ahead velocity
            ``v + a s / 2`` written here. p0, v0: (n,) current position [rad] and velocity [rad/s].
        s: step [s]. lower, upper, vmax, amax: (n,) the limits; two_over_a: (n,) ``2 / amax``.
        decel: the fraction of amax the braking before a stop plans with.
        lo, hi: (6, n) bounds of y's rows; rows 0 (positions) and 2 (accelerations) given, rows 1, 3, 4, 5
            written here. bad: (n,) written: True where a row of y is outside its bounds.

    Returns:
        the number of joints flagged in bad.
    """
    n = p0.shape[0]
    half_s = 0.5 * s
    count = 0
    for j in range(n):
        y[3, j] = y[0, j] - p0[j]
        y[4, j] = y[1, j] - v0[j]
        y[5, j] = y[2, j] * half_s + y[1, j]
        hi[3, j] = vmax[j] * s
        lo[3, j] = -hi[3, j]
        hi[4, j] = amax[j] * s
        lo[4, j] = -hi[4, j]
        # Far from both stops the braking bound exceeds vmax and the clamp to vmax below leaves +-vmax.
        below = -_brake(p0[j] - lower[j], s, amax[j], two_over_a[j], decel)
        above = _brake(upper[j] - p0[j], s, amax[j], two_over_a[j], decel)
        lo[1, j] = max(below, -vmax[j])
        hi[1, j] = min(above, vmax[j])
        lo[5, j] = lo[1, j]
        hi[5, j] = hi[1, j]
        out = False
        for r in range(6):
            if y[r, j] < lo[r, j] or y[r, j] > hi[r, j]:
                out = True
        bad[j] = out
        count += out
    return count


def warm_up() -> None:
    """Compile (or load from the cache) the kernel on a tiny problem, once a process: before any real-time tick
    (``QuinticSmoother`` does when built with limits)."""
    global _warm
    if _warm:
        return
    one = np.ones(1)
    limit_rows(np.zeros((6, 1)), np.zeros(1), np.zeros(1), 0.002, -one, one, one, one, 2.0 * one, 0.8,
               np.zeros((6, 1)), np.zeros((6, 1)), np.zeros(1, dtype=np.bool_))  # fmt: skip
    _warm = True


if __name__ == "__main__":
    # `python -m services.solver.quintic_kernel`: compile into the cache ahead of time (make setup, the image build).
    warm_up()
