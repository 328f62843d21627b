"""Quintic smoothing of the joint trajectory between solver outputs (seed 000, section 3), within limits.

Every tick a quintic polynomial runs from the current smoothed state (position,
velocity, acceleration) to a segment end: the solver's latest output
extrapolated over a short horizon T, with zero acceleration there. The command
is that polynomial one tick later (at the real elapsed time s). The next segment
starts from exactly that state, so the commanded trajectory is C2 whatever the
segment ends are.

That freedom is what keeps the command within its limits without breaking C2:
the state at s is affine in the segment end, so per joint the end is moved
along the line from the "keep the current velocity" end (lambda = 0) to the
desired end (lambda = 1), and the largest lambda <= 1 is taken for which the
next state respects the position limits, the velocity limit and the braking
distance before a position limit, the step |dq| <= vmax s, the acceleration
limit and |dqd| <= a_max s (lambda outside [0, 1] when needed). Only when no
lambda does is the state clamped, which breaks C2; that is counted, and with a
raw trajectory that keeps ``RAW_*_FRACTION`` of the limits it stays 0 in the
tests. With a constant-velocity raw trajectory the smoother follows it exactly.
"""

from __future__ import annotations

import math

import numpy as np

from services.solver.bounds import JointBounds

#: Fraction of a_max the smoother plans its braking before a position limit with: the headroom covers
#: a quintic piece covering more distance than the constant-velocity step the braking bound assumes.
BRAKE_DECEL = 0.8
#: Crossing of the lambda interval ends accepted as round-off.
LAMBDA_SLACK = 1e-9
#: Headroom the raw trajectory leaves the smoother: its velocity and acceleration bounds are these
#: fractions of the limits. The smoother lags and overshoots its input a little; with this headroom
#: the limiter always finds a segment end within the limits (0 clamps in 15 000 violent test ticks,
#: against about 1 in 150 ticks when the raw trajectory runs at the full limits).
RAW_VMAX_FRACTION = 0.95
RAW_AMAX_FRACTION = 0.5
#: ... and this much [rad] of each position limit: the smoother reaches a stop a little after its input.
RAW_POSITION_MARGIN = 0.01


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


def _coefficient_map(T: float) -> np.ndarray:
    """(6, 5) matrix C with (c0..c5) = C @ (p0, v0, a0, p1, v1) for a1 = 0 (``quintic_coefficients``)."""
    C = np.zeros((6, 5))
    for j in range(5):
        e = np.zeros(5)
        e[j] = 1.0
        C[:, j] = quintic_coefficients(e[0], e[1], e[2], e[3], e[4], 0.0, T)
    return C


class QuinticSmoother:
    """Receding-horizon quintic filter of a joint trajectory, kept within joint limits.

    Args:
        n: number of joints.
        dt: nominal tick [s]; the horizon is ``horizon_ticks * dt``.
        horizon_ticks: segment length T in ticks (>= 2; larger = smoother, slower to react).
        limits: position, velocity and acceleration limits of the output (None: unlimited).
        compiled: check the limits with the numba kernel (``tick_kernel``, compiled when built); False runs
            the numpy rows, the readable reference the kernel is tested against. Both give the same bits.
    """

    def __init__(
        self, n: int, dt: float, horizon_ticks: int = 4, limits: JointBounds | None = None, compiled: bool = True
    ):
        if horizon_ticks < 2:
            raise ValueError(f"horizon_ticks must be >= 2, got {horizon_ticks}")
        self.dt = dt
        self.T = horizon_ticks * dt
        self.limits = limits
        self.limited = 0  # joints whose segment end the limiter moved at the last step
        #: indices of the joints the last step clamped (C2 broken; empty in normal operation), for the reason text
        self.clamped_joints = np.zeros(0, dtype=np.int64)
        # State rows: p, v, a (smoothed) and the segment end p1, v1 (a1 = 0).
        self._S = np.zeros((5, n))
        self.p, self.v, self.a = self._S[0], self._S[1], self._S[2]
        self._C = _coefficient_map(self.T)
        self._s = -1.0
        self._K = np.zeros((3, 5))
        #: (3, 6) p, v, a rows of the monomials s^0..s^5 at the last step (``propagator``; constants set here)
        self._P = np.zeros((3, 6))
        self._P[0, 0] = self._P[1, 1] = 1.0
        self._P[2, 2] = 2.0
        self._Y = np.zeros((6, n))  # limited quantities of the next state (see _limit)
        self._lo = np.zeros((6, n))
        self._hi = np.zeros((6, n))
        self._limits_for: float | None = None  # the step s the s-dependent rows of _lo, _hi were set for
        self._dist = np.empty((2, n))  # distances to the stops below and above
        self._vmax_rows = False  # the velocity rows of _lo, _hi hold +-vmax (no braking bound tighter)
        self._bad = np.zeros(n, dtype=bool)  # joints out of their limits at the last check (compiled path)
        self._infeasible = np.zeros(n, dtype=bool)  # of those, the ones the line search cannot save (compiled path)
        self._p0_kept = np.zeros(n)  # their positions before the step (compiled path, for ``_clamp``)
        self._kernel = None
        if limits is not None:
            self._lo[0], self._hi[0] = limits.lower, limits.upper
            self._hi[2] = limits.amax
            np.negative(limits.amax, out=self._lo[2])
            if compiled:
                # Imported here: only a smoother with limits loads numba, and it compiles now, not on a tick.
                from services.solver import tick_kernel

                tick_kernel.warm_up()
                self._kernel = tick_kernel

    def propagator(self, s: float) -> np.ndarray:
        """(3, 5) map from (p0, v0, a0, p1, v1) to (p, v, a) at s [s] into the segment (cached for the last s)."""
        if s != self._s:
            # Written into a kept buffer, entry by entry: a fresh np.array of nested lists costs several times
            # more, and the step changes every tick (the real time between ticks).
            s2, s3 = s * s, s * s * s
            P = self._P
            P[0, 1:] = s, s2, s3, s3 * s, s3 * s2
            P[1, 2:] = 2.0 * s, 3.0 * s2, 4.0 * s3, 5.0 * s3 * s
            P[2, 3:] = 6.0 * s, 12.0 * s2, 20.0 * s3
            np.matmul(P, self._C, out=self._K)
            self._s = s
        return self._K

    @property
    def segment_end(self) -> tuple[np.ndarray, np.ndarray]:
        """(p1, v1) (n,) of the segment the last step was evaluated on (a1 = 0); views."""
        return self._S[3], self._S[4]

    def reset(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Start at rest (or at qd (n,) [rad/s]) at q (n,) [rad]."""
        self.p[:] = q
        self.v[:] = 0.0 if qd is None else qd
        self.a[:] = 0.0

    def step(self, q_raw: np.ndarray, qd_raw: np.ndarray, s: float | None = None) -> int:
        """Advance by s [s] (default: the nominal tick) towards the raw state q_raw (n,) [rad], qd_raw (n,) [rad/s].

        Returns:
            number of joints whose state had to be clamped (C2 broken; 0 in normal operation).
            The new state is in ``p``, ``v``, ``a``; ``limited`` says how many joints took a
            shortened segment (C2 kept).
        """
        s = self.dt if s is None else s
        if not 0.0 < s < self.T:
            raise ValueError(f"step {s} s must be in (0, {self.T}) s")
        # A late tick (s up to 2 nominal ticks) is advanced in sub-steps of at most one tick: the limits
        # hold at every sub-step, as for on-time ticks. One long step could leave no segment end that
        # respects them all (a joint at its speed cap, its braking bound shrinking with the step) and
        # take the C2-breaking clamp: 7 clamps over the unsafe-target cases at a steady 4 ms, 0 at 2 ms.
        n = max(1, math.ceil(s / self.dt - 1e-9))
        clamped = limited = 0
        if self.clamped_joints.size:
            self.clamped_joints = self.clamped_joints[:0]
        for _ in range(n):
            clamped = max(clamped, self._advance(q_raw, qd_raw, s / n))
            limited = max(limited, self.limited)
        self.limited = limited
        return clamped

    def _advance(self, q_raw: np.ndarray, qd_raw: np.ndarray, s: float) -> int:
        """One step of s [s] (at most a nominal tick) towards the raw state; returns the joints clamped."""
        S = self._S
        K = self.propagator(s)
        # Aim at where the raw trajectory will be at the end of the horizon if its velocity holds.
        np.multiply(qd_raw, self.T - self.dt, out=S[3])
        S[3] += q_raw
        S[4] = qd_raw
        nxt = np.matmul(K, S, out=self._Y[:3])
        self.limited = 0
        if self.limits is None:
            S[:3] = nxt
            return 0
        return self._limit(nxt, s)

    def _limit(self, nxt: np.ndarray, s: float) -> int:
        """Take the next state nxt (3, n) or the nearest one along the segment-end line that respects the limits."""
        lim, S, y, lo, hi = self.limits, self._S, self._Y, self._lo, self._hi
        p0, v0 = S[0], S[1]
        if self._kernel is not None:
            bad = self._bad
            limited = self._kernel.smoother_rows(
                y, p0, v0, s, lim.lower, lim.upper, lim.vmax, lim.amax, lim.two_over_a, BRAKE_DECEL, lo, hi, bad
            )
            if not limited:
                S[:3] = nxt
                return 0
            self._limits_for = None  # the kernel wrote the rows the numpy path caches
            self._vmax_rows = False
            # The line search compiled as well (``_line_search``'s steps); a joint it cannot save is clamped here.
            self.limited = limited
            infeasible = self._infeasible
            if not self._kernel.line_search(S, y, lo, hi, self._K, bad, self.T, s, LAMBDA_SLACK, self._p0_kept,
                                            infeasible):  # fmt: skip
                return 0
            idx = np.flatnonzero(infeasible)
            return self._clamp(idx, self._p0_kept[idx], s)
        bad = self._smoother_rows(s)
        if not bad.any():
            S[:3] = nxt
            return 0
        return self._line_search(nxt, bad, s)

    def _smoother_rows(self, s: float) -> np.ndarray:
        """The numpy reference of ``tick_kernel.smoother_rows``: y's rows 3-5 and their bounds at step s [s];
        returns the (n,) mask of joints with a row out of its bounds."""
        lim, S, y, lo, hi = self.limits, self._S, self._Y, self._lo, self._hi
        p0, v0 = S[0], S[1]
        # Quantities limited at the next state, all affine in the segment end (rows: p, v, a, dp, dv,
        # v + a s / 2); nxt was computed into y[:3] (``_advance``).
        np.subtract(y[0], p0, out=y[3])
        np.subtract(y[1], v0, out=y[4])
        # Velocity half a step ahead: a state at its velocity bound must not still accelerate outwards.
        np.multiply(y[2], 0.5 * s, out=y[5])
        y[5] += y[1]
        if s != self._limits_for:
            # The rows that depend on s only (p and a bounds are constant, set in __init__).
            np.multiply(lim.vmax, s, out=hi[3])
            np.negative(hi[3], out=lo[3])
            np.multiply(lim.amax, s, out=hi[4])
            np.negative(hi[4], out=lo[4])
            self._limits_for = s
        d = self._dist
        np.subtract(p0, lim.lower, out=d[0])
        np.subtract(lim.upper, p0, out=d[1])
        if lim.braking_free(d, s, BRAKE_DECEL):
            # Far from every stop the braking bound allows more than vmax: the velocity rows are +-vmax exactly.
            if not self._vmax_rows:
                lo[1], hi[1] = lim._neg_vmax, lim.vmax
                lo[5], hi[5] = lo[1], hi[1]
                self._vmax_rows = True
        else:
            below, above = lim.brake_both(d[0], d[1], s, decel=BRAKE_DECEL)
            np.maximum(below, lim._neg_vmax, out=lo[1])
            np.minimum(above, lim.vmax, out=hi[1])
            lo[5], hi[5] = lo[1], hi[1]
            self._vmax_rows = False
        return ((y < lo) | (y > hi)).any(axis=0)

    def _line_search(self, nxt: np.ndarray, bad: np.ndarray, s: float) -> int:
        """The next state nxt (3, n) with the segment end of each bad joint (n,) mask moved back along the line
        until its limits hold (y's rows and their bounds filled by ``_smoother_rows``); returns the joints clamped.
        The numpy reference of ``tick_kernel.line_search``."""
        S, y, lo, hi = self._S, self._Y, self._lo, self._hi
        p0, v0 = S[0], S[1]
        # Per bad joint: lambda in [0, 1] on the line from the keep-velocity end to the desired end.
        K = self._K
        idx = np.flatnonzero(bad)
        dp1 = S[3, idx] - (p0[idx] + v0[idx] * self.T)
        dv1 = S[4, idx] - v0[idx]
        dnxt = np.outer(K[:, 3], dp1) + np.outer(K[:, 4], dv1)  # (3, k): next state per unit lambda
        dy = np.stack([dnxt[0], dnxt[1], dnxt[2], dnxt[0], dnxt[1], dnxt[1] + 0.5 * s * dnxt[2]])
        y0 = y[:, idx] - dy  # next-state quantities at lambda = 0
        lam_hi, lam_lo = _interval(y0[:5], dy[:5], lo[:5, idx], hi[:5, idx])
        # The look-ahead row only where it is compatible with the limits proper.
        ahead_hi, ahead_lo = _interval(y0[5:], dy[5:], lo[5:, idx], hi[5:, idx])
        both = np.maximum(lam_lo, ahead_lo) <= np.minimum(lam_hi, ahead_hi)
        lam_lo = np.where(both, np.maximum(lam_lo, ahead_lo), lam_lo)
        lam_hi = np.where(both, np.minimum(lam_hi, ahead_hi), lam_hi)
        # A joint resting on its stop pins lambda from both sides; round-off may cross them by ~1e-16.
        feasible = lam_lo <= lam_hi + LAMBDA_SLACK
        lam = np.minimum(np.maximum(1.0, lam_lo), np.maximum(lam_hi, lam_lo))
        lam[~feasible] = 0.0
        p0_bad = p0[idx]  # fancy indexing copies: kept for the clamp below
        S[:3] = nxt
        S[:3, idx] -= dnxt * (1.0 - lam)
        S[3, idx] -= dp1 * (1.0 - lam)
        S[4, idx] -= dv1 * (1.0 - lam)
        self.limited = int(idx.size)
        if feasible.all():
            return 0
        return self._clamp(idx[~feasible], p0_bad[~feasible], s)

    def _clamp(self, idx: np.ndarray, p0: np.ndarray, s: float) -> int:
        """Last resort (breaks C2): clamp the state of joints idx (previous positions p0) into the limits."""
        lim, S = self.limits, self._S
        step = lim.vmax[idx] * s
        lo_p = np.maximum(lim.lower[idx], p0 - step)
        hi_p = np.minimum(lim.upper[idx], p0 + step)
        S[0, idx] = np.minimum(np.maximum(S[0, idx], lo_p), hi_p)
        S[1, idx] = np.minimum(np.maximum(S[1, idx], self._lo[1, idx]), self._hi[1, idx])
        S[2, idx] = np.clip(S[2, idx], -lim.amax[idx], lim.amax[idx])
        self.clamped_joints = np.union1d(self.clamped_joints, idx)
        return int(idx.size)


def _interval(y0: np.ndarray, dy: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the lambda interval [lam_lo, lam_hi] with lo <= y0 + lam dy <= hi in every row."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (lo - y0) / dy
        b = (hi - y0) / dy
    up = np.where(dy > 0, b, np.where(dy < 0, a, np.inf))
    down = np.where(dy > 0, a, np.where(dy < 0, b, -np.inf))
    # Rows that lambda does not move: feasible or not whatever lambda is.
    stuck = (dy == 0) & ((y0 < lo) | (y0 > hi))
    up = np.where(stuck, -np.inf, up)
    return up.min(axis=0), down.max(axis=0)
