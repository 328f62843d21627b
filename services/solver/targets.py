"""Task targets between mocap frames: extrapolated with their velocities (and, optionally, the acceleration between
consecutive frames), held when invalid or stale."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from shared.messages import Header, TaskTargets
from shared.rotations import quat_to_matrix
from shared.targets import TARGET_NAMES

#: (3,) zero velocity of a sample at rest, shared by every such sample (read-only: samples are never written).
_AT_REST = np.zeros(3)
_AT_REST.flags.writeable = False


@dataclass(slots=True)
class TargetSample:
    """One target at one instant (base frame): p (3,) [m], R (3, 3), v (3,) [m/s], w (3,) [rad/s]."""

    p: np.ndarray
    R: np.ndarray
    v: np.ndarray
    w: np.ndarray
    use_rotation: bool
    held: bool


@dataclass(slots=True)
class _Stored:
    p: np.ndarray
    R: np.ndarray
    v: np.ndarray
    w: np.ndarray
    use_rotation: bool
    t: float
    held: bool
    #: source stamp [s] of the frame (the acceleration's time base)
    stamp: float = 0.0
    #: (3,) [m/s^2] the acceleration extrapolated with (the estimate times its fitted share), or None
    a: np.ndarray | None = None
    #: [s] how far the published velocity lags the frame (the re-centring lead)
    lead: float = 0.0
    #: (3,) [m/s^2] the acceleration estimate from the last two frames, or None
    a_raw: np.ndarray | None = None
    #: running sums of the share fit: miss . correction and correction . correction [m^2]
    fit_num: float = 0.0
    fit_den: float = 0.0


class TargetTracker:
    """Latest targets per name, sampled at solver time.

    A valid target is extrapolated from its arrival time with its own velocity
    for at most ``horizon`` [s] (the gap between mocap frames) and then held.
    An invalid one keeps the last valid pose at rest. When no message arrived
    for ``timeout`` [s] every target is held at rest.

    With ``acceleration`` the positions follow a parabola instead: the acceleration ``a`` is the change of
    the published velocity since the target's previous frame over their stamps' interval ``D`` (0 after a
    gap longer than ``2 horizon``, a held or a first frame), and the published velocity is taken to lag the
    frame by ``velocity_lag * D`` (a backward difference is the velocity half a frame back: 0.5), so at age
    ``tau`` [s] ``p = p0 + v tau + a (L tau + tau^2 / 2)`` with ``L = velocity_lag * D`` and the velocity fed
    forward is ``v + a (L + tau)``. Why: with constant velocity each new frame lands ``a D^2`` away from the
    extrapolation (0.8 cm mean on a 30 fps wave), a step the arm then closes over ~10 ticks under its
    acceleration limits; that step was most of the gesture clips' wrist error. Orientations keep constant
    angular velocity.

    Args:
        horizon: longest extrapolation [s].
        timeout: age after which the stream counts as stale [s].
        acceleration: extrapolate positions with the acceleration between consecutive frames (above).
        velocity_lag: the published velocity's lag, in frame intervals (used with ``acceleration``).
        acceleration_memory: frames over which the share of the acceleration estimate is fitted (0: use all
            of it; see ``_estimate_acceleration``).
    """

    def __init__(
        self,
        horizon: float = 0.05,
        timeout: float = 0.5,
        names: tuple[str, ...] = TARGET_NAMES,
        acceleration: bool = False,
        velocity_lag: float = 0.5,
        acceleration_memory: float = 10.0,
    ):
        self.horizon = horizon
        self.timeout = timeout
        self.names = names
        self.acceleration = acceleration
        self.velocity_lag = velocity_lag
        self.acceleration_memory = acceleration_memory
        self._store: dict[str, _Stored] = {}
        self.last_rx: float | None = None
        self.hdr = Header(0, 0.0, 0)
        self.invalid_count = 0
        # Samples of the current solver time: a tick asks for a name more than once (the posture level
        # and the tasks), and the extrapolation (an exp3 per rotating target) is the same each time.
        self._memo: dict[str, TargetSample | None] = {}
        self._memo_t: float | None = None

    @classmethod
    def for_solver(cls, cfg) -> TargetTracker:
        """The tracker a solver configured by ``cfg`` (a ``SolverConfig``: ``target_horizon``, ``target_timeout``,
        ``target_acceleration``, ``target_velocity_lag``, ``target_acceleration_memory``) samples its targets with."""
        return cls(
            cfg.target_horizon,
            cfg.target_timeout,
            acceleration=cfg.target_acceleration,
            velocity_lag=cfg.target_velocity_lag,
            acceleration_memory=cfg.target_acceleration_memory,
        )

    @property
    def started(self) -> bool:
        """True once any valid target has arrived."""
        return bool(self._store)

    def stale(self, t: float) -> bool:
        """True when the last message is older than the timeout at solver time t [s]."""
        return self.last_rx is None or t - self.last_rx > self.timeout

    def update(self, msg: TaskTargets, t: float) -> None:
        """Take a new message received at solver time t [s]."""
        self.last_rx = t
        self.hdr = msg.hdr
        self._memo_t = None
        for name, tg in msg.targets.items():
            if name not in self.names:
                continue
            if tg.valid:
                new = _Stored(tg.p.copy(), quat_to_matrix(tg.q), tg.v.copy(), tg.w.copy(), tg.use_rotation, t, False)
                new.stamp = msg.hdr.stamp
                if self.acceleration:
                    self._estimate_acceleration(new, self._store.get(name))
                self._store[name] = new
            else:
                self.invalid_count += 1
                old = self._store.get(name)
                if old is not None and not old.held:
                    # Freeze where the extrapolation had got to, at rest.
                    s = self.sample(name, t)
                    self._store[name] = _Stored(s.p, s.R, np.zeros(3), np.zeros(3), old.use_rotation, t, True)
                    self._memo_t = None

    def _estimate_acceleration(self, new: _Stored, old: _Stored | None) -> None:
        """Set ``new.a`` and ``new.lead`` from the previous frame ``old`` of the same target (none: constant
        velocity).

        The share of the estimate used is fitted on the frames themselves: at each frame, what the previous
        frame's constant-velocity prediction missed by is regressed on the correction its parabola added,
        over the last ``acceleration_memory`` frames (exponential weights), and the slope, clipped to [0, 1],
        scales the new estimate. On smooth motion it is about 1; where the velocity differences are noise
        (marker jitter at 100+ Hz, jerky frames) the correction does not predict the miss and it drops
        towards 0, the constant-velocity extrapolation.
        """
        if old is None or old.held:
            return
        d = new.stamp - old.stamp
        if not 0.0 < d <= 2.0 * self.horizon:  # a repeated, reordered or restarted stamp, or a gap
            return
        new.a_raw = (new.v - old.v) / d
        new.lead = self.velocity_lag * d
        if self.acceleration_memory <= 0:
            new.a = new.a_raw
            return
        num, den = old.fit_num, old.fit_den
        if old.a_raw is not None:
            tau = min(d, self.horizon)
            correction = old.a_raw * (old.lead * tau + 0.5 * tau * tau)
            miss = new.p - (old.p + old.v * tau)
            b = 1.0 / self.acceleration_memory
            num = (1.0 - b) * num + b * float(miss @ correction)
            den = (1.0 - b) * den + b * float(correction @ correction)
        new.fit_num, new.fit_den = num, den
        share = min(max(num / den, 0.0), 1.0) if den > 0.0 else 0.0
        if share > 0.0:
            new.a = share * new.a_raw

    def sample(self, name: str, t: float) -> TargetSample | None:
        """Target ``name`` at solver time t [s], or None if it never was valid (shared until the next update or
        time: do not write into it)."""
        if t != self._memo_t:
            self._memo.clear()
            self._memo_t = t
        elif name in self._memo:
            return self._memo[name]
        out = self._memo[name] = self._sample(name, t)
        return out

    def _sample(self, name: str, t: float) -> TargetSample | None:
        s = self._store.get(name)
        if s is None:
            return None
        age = t - s.t
        stale = self.stale(t)
        if s.held or age <= 0.0:
            v = _AT_REST if s.held or stale else s.v if s.a is None else s.v + s.a * s.lead
            return TargetSample(s.p, s.R, v, s.w, s.use_rotation, s.held)
        tau = min(age, self.horizon)
        if s.a is None:
            p, v = s.p + s.v * tau, s.v
        else:
            p = s.p + s.v * tau + s.a * (s.lead * tau + 0.5 * tau * tau)
            v = s.v + s.a * (s.lead + tau)
        R = pin.exp3(s.w * tau) @ s.R if s.use_rotation else s.R
        if age < self.horizon and not stale:
            return TargetSample(p, R, v, s.w, s.use_rotation, False)
        return TargetSample(p, R, _AT_REST, _AT_REST, s.use_rotation, stale)
