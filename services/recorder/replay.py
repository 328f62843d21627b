"""Replay schedule of a recording: which message goes where, and when.

Timing comes from the receive times (``log_time``) of the recording: message
``i`` is due ``(log_time[i] - log_time[0]) / speed`` seconds after the start.
The caller sleeps to absolute monotonic deadlines, so timing errors do not
accumulate over a long replay.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import zenoh

from shared.keys import Keys


def rebase_key(key: str, session: str) -> str:
    """``key`` moved from its own session to ``session`` (``mimic/<s>/rest`` -> ``mimic/<session>/rest``).

    Raises:
        ValueError: ``key`` is not a mimic session key, or ``session`` is not one key chunk.
    """
    return Keys.with_session(key, session)


def key_filter(pattern: str | None) -> zenoh.KeyExpr | None:
    """Key expression a recorded key must lie inside to be replayed.

    ``pattern`` is a Zenoh key expression; one not starting with ``mimic/`` is
    taken relative to any session (``mocap/frame`` -> ``mimic/*/mocap/frame``).
    """
    if not pattern:
        return None
    return zenoh.KeyExpr(Keys.in_any_session(pattern))


@dataclass(slots=True)
class Due:
    """One message to publish ``offset`` seconds after the replay start."""

    offset: float  # [s] from the start of the replay (0 in fast mode)
    key: str  # destination key
    data: bytes


class ReplayPlan:
    """Turn recorded messages into timed publications.

    Args:
        speed: time scale (2.0 = twice as fast); None = as fast as possible.
        only: keep only keys inside this key expression (see :func:`key_filter`).
        session: republish into this session instead of the recorded one.
    """

    def __init__(self, speed: float | None = 1.0, only: str | None = None, session: str | None = None):
        if speed is not None and speed <= 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        if session is not None:
            Keys(session)  # validates the chunk before anything is published
        self.speed = speed
        self.only = key_filter(only)
        self.session = session
        self.skipped = 0

    def keep(self, key: str) -> bool:
        """Whether a recorded key passes ``--only``."""
        return self.only is None or self.only.includes(zenoh.KeyExpr(key))

    def step(self, key: str, data: bytes, log_time: int, t_first: int) -> Due:
        """Destination and due time of one kept message; ``t_first`` = log_time of the first kept [ns]."""
        dest = rebase_key(key, self.session) if self.session else key
        offset = 0.0 if self.speed is None else (log_time - t_first) * 1e-9 / self.speed
        return Due(offset, dest, data)

    def plan(self, records: Iterable) -> Iterator[Due]:
        """Due publications of ``records`` (objects with key, data, log_time [ns]), in order."""
        t_first = None
        for r in records:
            if not self.keep(r.key):
                self.skipped += 1
                continue
            if t_first is None:
                t_first = r.log_time
            yield self.step(r.key, r.data, r.log_time, t_first)
