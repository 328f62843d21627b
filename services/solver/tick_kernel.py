"""The elementwise arithmetic of a solver tick compiled with numba: task rows, the box, the smoother's check.

Why compiled: the frame tasks' rows (``FrameRows``: ``A = W J``, ``b = W (v_ff + gain e)`` of every wrist
and elbow task), the range centring's weights and rows (``RangeCentringTask``), ``JointBounds.compute``
(the box every level is solved in), the clip and integration of the solution (``SolverCore``) and the
smoother's limit check (``QuinticSmoother``: six limited
quantities of the next state against their bounds) are 10 to 25 numpy calls each on vectors of 5 to 40
elements a tick: a microsecond of call overhead each for a few hundred flops. Here one loop does each.
Every element goes through the numpy path's operations in the same order, so the results are the same
bits; the numpy paths stay the readable references and the tests hold these kernels to them
(``tests/solver/test_frame_rows.py``, ``test_centring.py``, ``test_bounds.py``, ``test_quintic.py``,
``test_core.py``). A tick with a joint out of the smoother's limits takes the compiled line search too; only a
joint no segment end keeps within its limits takes the numpy clamp (``QuinticSmoother._clamp``).

In the box and the smoother's check, far from both stops the braking bound exceeds vmax, so the numpy paths
skip it there (``braking_free``); here it is always computed: intersected before the clamp to +-vmax, a
looser bound changes no bit.

Compilation: ``cache=True`` as ``hqp_kernel``; :func:`warm_up` compiles or loads it before the first tick.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_warm = False


@njit(cache=True)
def _brake(distance: float, dt: float, amax: float, two_over_a: float, decel: float) -> float:
    """``JointBounds.brake`` of one joint: the fastest speed [rad/s] towards a stop ``distance`` [rad] away."""
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
def smoother_rows(y, p0, v0, s, lower, upper, vmax, amax, two_over_a, decel, lo, hi, bad):
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


@njit(cache=True)
def line_search(S, y, lo, hi, K, bad, T, s, slack, p0_kept, infeasible):
    """``QuinticSmoother._line_search``: the next state with each bad joint's segment end moved back along the line
    from the keep-velocity end until its limits hold.

    Args:
        S: (5, n) the smoother's state p, v, a and segment end p1, v1: rows 0-2 set to the next state (y's rows
            0-2, moved back for the bad joints), rows 3-4 moved back for the bad joints.
        y, lo, hi: (6, n) the limited quantities of the desired next state and their bounds (``smoother_rows``).
        K: (3, 5) the propagator of step s [s]. bad: (n,) the joints out of their limits. T: horizon [s].
        slack: ``LAMBDA_SLACK``. p0_kept: (n,) written for the bad joints: their position before the step.
        infeasible: (n,) written: the bad joints no lambda puts within their limits (to be clamped).

    Returns:
        the number of infeasible joints.
    """
    count = 0
    for j in range(S.shape[1]):
        infeasible[j] = False
        if not bad[j]:
            for r in range(3):
                S[r, j] = y[r, j]
            continue
        p0 = S[0, j]
        v0 = S[1, j]
        p0_kept[j] = p0
        dp1 = S[3, j] - (p0 + v0 * T)
        dv1 = S[4, j] - v0
        d0 = K[0, 3] * dp1 + K[0, 4] * dv1
        d1 = K[1, 3] * dp1 + K[1, 4] * dv1
        d2 = K[2, 3] * dp1 + K[2, 4] * dv1
        lam_hi = np.inf
        lam_lo = -np.inf
        for r in range(5):
            dy = d0 if r == 0 or r == 3 else (d1 if r == 1 or r == 4 else d2)
            up, down = _lambda_range(y[r, j] - dy, dy, lo[r, j], hi[r, j])
            lam_hi = min(lam_hi, up)
            lam_lo = max(lam_lo, down)
        # The look-ahead row only where it is compatible with the limits proper.
        dy = d1 + 0.5 * s * d2
        ahead_hi, ahead_lo = _lambda_range(y[5, j] - dy, dy, lo[5, j], hi[5, j])
        if max(lam_lo, ahead_lo) <= min(lam_hi, ahead_hi):
            lam_lo = max(lam_lo, ahead_lo)
            lam_hi = min(lam_hi, ahead_hi)
        lam = min(max(1.0, lam_lo), max(lam_hi, lam_lo))
        if not lam_lo <= lam_hi + slack:
            lam = 0.0
            infeasible[j] = True
            count += 1
        back = 1.0 - lam
        S[0, j] = y[0, j] - d0 * back
        S[1, j] = y[1, j] - d1 * back
        S[2, j] = y[2, j] - d2 * back
        S[3, j] -= dp1 * back
        S[4, j] -= dv1 * back
    return count


@njit(cache=True)
def _lambda_range(y0: float, dy: float, lo: float, hi: float) -> tuple[float, float]:
    """``quintic._interval`` of one row: (up, down) with lo <= y0 + lam dy <= hi for lam in [down, up]; up = -inf
    when lam does not move the row and it is out of its bounds."""
    if dy > 0:
        return (hi - y0) / dy, (lo - y0) / dy
    if dy < 0:
        return (lo - y0) / dy, (hi - y0) / dy
    return (-np.inf if dy == 0 and (y0 < lo or y0 > hi) else np.inf), -np.inf


@njit(cache=True)
def velocity_box(q, qd_prev, dt, lower, upper, vmax, amax, two_over_a, window, w_lo, w_hi, lb, ub):
    """``JointBounds.compute``: the box lb, ub (n,) [rad/s] (written) for a step dt [s] from q (n,) [rad] moving
    at qd_prev (n,) [rad/s], within the limits lower, upper, vmax, amax (n,) (two_over_a: ``2 / amax``) and,
    when ``window``, the braking window w_lo, w_hi (n,) [rad]. Terms intersected in the same order."""
    for j in range(q.shape[0]):
        if window:
            lo = -_brake(q[j] - w_lo[j], dt, amax[j], two_over_a[j], 1.0)
            hi = _brake(w_hi[j] - q[j], dt, amax[j], two_over_a[j], 1.0)
        else:
            lo = -np.inf
            hi = np.inf
        a_dt = amax[j] * dt
        lo, hi = _intersect(lo, hi, qd_prev[j] - a_dt, qd_prev[j] + a_dt)
        below = -_brake(q[j] - lower[j], dt, amax[j], two_over_a[j], 1.0)
        lo, hi = _intersect(lo, hi, below, _brake(upper[j] - q[j], dt, amax[j], two_over_a[j], 1.0))
        lb[j], ub[j] = _intersect(lo, hi, -vmax[j], vmax[j])


@njit(cache=True)
def _intersect(lb: float, ub: float, lo: float, hi: float) -> tuple[float, float]:
    """``JointBounds._intersect`` of one joint: [lb, ub] within [lo, hi]; [lo, hi] wins where they are disjoint."""
    return min(max(lb, lo), hi), min(max(ub, lo), hi)


@njit(cache=True)
def frame_rows(e, p_target, p, pos_rows, pos_src, gain, row_task, ff, cost, J, src, dst, A_all, b_all):
    """``FrameRows.fill``'s arithmetic: the position errors into e, then every row's A and b into the stack.

    Args:
        e: (R,) error rows, the orientation ones given (``log3``), the position ones written here:
            ``e[pos_rows] = p_target - p[pos_src]`` with p_target (P,) [m] and p (3F,) the frames' positions [m].
        gain: (T,) per task [1/s], row_task (R,) each row's task. ff, cost: (R,) feed-forward and weight per row.
        J: (6F, n) the frames' Jacobians stacked; src (R,) the row of J each row scales, dst (R,) its stack row.
        A_all, b_all: (rows, n) and (rows,) the stack, rows dst written.
    """
    for i in range(pos_rows.shape[0]):
        e[pos_rows[i]] = p_target[i] - p[pos_src[i]]
    for r in range(e.shape[0]):
        c = cost[r]
        d = dst[r]
        b_all[d] = (e[r] * gain[row_task[r]] + ff[r]) * c
        for j in range(J.shape[1]):
            A_all[d, j] = c * J[src[r], j]


@njit(cache=True)
def clip_and_integrate(qd, lb, ub, dt, lower, upper, q, qd_out):
    """``SolverCore._checked_velocity`` then ``_integrate``: qd (n,) [rad/s] clipped into [lb, ub] into qd_out, and
    q (n,) [rad] advanced by ``qd_out dt`` [s] and clipped into [lower, upper] (both written in place).

    Returns:
        the largest ``|qd_out - qd|`` [rad/s] (the safety clamp's size); -1 when qd has a non-finite element,
        and then nothing is written (the caller brakes instead).
    """
    n = qd.shape[0]
    for j in range(n):
        if not math.isfinite(qd[j]):
            return -1.0
    worst = 0.0
    for j in range(n):
        c = min(max(qd[j], lb[j]), ub[j])
        worst = max(worst, abs(c - qd[j]))
        qd_out[j] = c
        q[j] = min(max(q[j] + c * dt, lower[j]), upper[j])
    return worst


@njit(cache=True)
def centring_weights(q, joints, lower, upper, span, band, peak, cost):
    """``RangeCentringTask.update``: the weights cost (k,) of the joints ``q[joints]`` [rad] from their stops
    lower, upper (k,) [rad] (span: upper - lower): 0 beyond the band, ``peak`` at a stop."""
    for i in range(joints.shape[0]):
        qj = q[joints[i]]
        w = max(0.0, 1.0 - min(qj - lower[i], upper[i] - qj) / span[i] / band)
        cost[i] = peak * (w * w)


@njit(cache=True)
def centring_rows(q, joints, inner_lower, inner_upper, gain, ff, cost, J, err, A, b):
    """``RangeCentringTask``'s rows: err (k,) [rad] the depth of ``q[joints]`` into the band, ``A = W J`` (k, n),
    ``b = W (v_ff + gain err)`` (k,) (the base ``Task.fill_qp_objective``'s steps)."""
    for i in range(joints.shape[0]):
        qj = q[joints[i]]
        e = min(max(qj, inner_lower[i]), inner_upper[i]) - qj
        err[i] = e
        c = cost[i]
        b[i] = (e * gain + ff[i]) * c
        for j in range(J.shape[1]):
            A[i, j] = c * J[i, j]


def warm_up() -> None:
    """Compile (or load from the cache) the kernel on a tiny problem, once a process: before any real-time tick
    (``FrameRows``, ``RangeCentringTask``, ``QuinticSmoother`` and ``JointBounds`` do when built compiled)."""
    global _warm
    if _warm:
        return
    one = np.ones(1)
    smoother_rows(np.zeros((6, 1)), np.zeros(1), np.zeros(1), 0.002, -one, one, one, one, 2.0 * one, 0.8,
                  np.zeros((6, 1)), np.zeros((6, 1)), np.zeros(1, dtype=np.bool_))  # fmt: skip
    i1 = np.zeros(1, dtype=np.intp)
    frame_rows(np.zeros(1), np.zeros(1), np.zeros(3), i1, i1, np.ones(1), i1, np.zeros(1), one, np.zeros((6, 1)), i1,
               i1, np.zeros((1, 1)), np.zeros(1))  # fmt: skip
    centring_weights(np.zeros(1), i1, -one, one, 2.0 * one, 0.25, 3.0, np.zeros(1))
    centring_rows(np.zeros(1), i1, -one, one, 20.0, np.zeros(1), one, np.ones((1, 1)), np.zeros(1), np.zeros((1, 1)),
                  np.zeros(1))  # fmt: skip
    b1 = np.ones(1, dtype=np.bool_)
    line_search(np.zeros((5, 1)), np.zeros((6, 1)), -np.ones((6, 1)), np.ones((6, 1)), np.zeros((3, 5)), b1, 0.008,
                0.002, 1e-12, np.zeros(1), b1.copy())  # fmt: skip
    clip_and_integrate(np.zeros(1), -one, one, 0.002, -one, one, np.zeros(1), np.zeros(1))
    for window in (False, True):
        velocity_box(np.zeros(1), np.zeros(1), 0.002, -one, one, one, one, 2.0 * one, window, -one, one,
                     np.zeros(1), np.zeros(1))  # fmt: skip
    _warm = True


if __name__ == "__main__":
    # `python -m services.solver.tick_kernel`: compile into the cache ahead of time (make setup, the image build).
    warm_up()
