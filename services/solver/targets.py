"""Task targets between mocap frames: extrapolated with their velocities, held when invalid or stale."""

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


class TargetTracker:
    """Latest targets per name, sampled at solver time.

    A valid target is extrapolated from its arrival time with its own velocity
    for at most ``horizon`` [s] (the gap between mocap frames) and then held.
    An invalid one keeps the last valid pose at rest. When no message arrived
    for ``timeout`` [s] every target is held at rest.

    Args:
        horizon: longest extrapolation [s].
        timeout: age after which the stream counts as stale [s].
    """

    def __init__(self, horizon: float = 0.05, timeout: float = 0.5, names: tuple[str, ...] = TARGET_NAMES):
        self.horizon = horizon
        self.timeout = timeout
        self.names = names
        self._store: dict[str, _Stored] = {}
        self.last_rx: float | None = None
        self.hdr = Header(0, 0.0, 0)
        self.invalid_count = 0
        # Samples of the current solver time: a tick asks for a name more than once (the posture level
        # and the tasks), and the extrapolation (an exp3 per rotating target) is the same each time.
        self._memo: dict[str, TargetSample | None] = {}
        self._memo_t: float | None = None

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
                self._store[name] = _Stored(
                    tg.p.copy(), quat_to_matrix(tg.q), tg.v.copy(), tg.w.copy(), tg.use_rotation, t, False
                )
            else:
                self.invalid_count += 1
                old = self._store.get(name)
                if old is not None and not old.held:
                    # Freeze where the extrapolation had got to, at rest.
                    s = self.sample(name, t)
                    self._store[name] = _Stored(s.p, s.R, np.zeros(3), np.zeros(3), old.use_rotation, t, True)
                    self._memo_t = None

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
            return TargetSample(s.p, s.R, s.v if not (s.held or stale) else _AT_REST, s.w, s.use_rotation, s.held)
        tau = min(age, self.horizon)
        p = s.p + s.v * tau
        R = pin.exp3(s.w * tau) @ s.R if s.use_rotation else s.R
        if age < self.horizon and not stale:
            return TargetSample(p, R, s.v, s.w, s.use_rotation, False)
        return TargetSample(p, R, _AT_REST, _AT_REST, s.use_rotation, stale)
