"""A test's own client session on a router: decoded messages of a key queued, publishers by key."""

from __future__ import annotations

import queue
from collections.abc import Callable
from typing import Any

import zenoh

from shared.bus import bus_args, zenoh_config


class BusClient:
    """A Zenoh client session of a test (or a test's stand-in for a service) on ``endpoint``.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, endpoint: str):
        self.session = zenoh.open(zenoh_config(bus_args(connect=[endpoint])))
        self._subs: list[zenoh.Subscriber] = []  # held, so they live as long as the session

    def inbox(self, key: str, decode: Callable[[bytes], Any]) -> queue.Queue:
        """A queue that receives ``decode(payload)`` of every sample on ``key``, in arrival order."""
        q: queue.Queue = queue.Queue()
        self._subs.append(self.session.declare_subscriber(key, lambda s: q.put(decode(s.payload.to_bytes()))))
        return q

    def publisher(self, key: str) -> zenoh.Publisher:
        return self.session.declare_publisher(key)

    def close(self) -> None:
        self.session.close()

    def __enter__(self) -> BusClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def drain(q: queue.Queue) -> list:
    """Everything queued in ``q`` now, oldest first (without waiting)."""
    out = []
    while not q.empty():
        out.append(q.get_nowait())
    return out
