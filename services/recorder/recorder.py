"""Lossless recorder core: the bus callback only enqueues, a writer thread writes.

The callback runs on a Zenoh thread and must never block it (a blocked
callback back-pressures or drops upstream), so it appends to an unbounded
deque. :meth:`Recorder.step` drains the deque into the
:class:`~services.recorder.mcap_io.RecordingWriter` and flushes the file every
``flush_period`` seconds so that a SIGKILL loses at most that much.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from pathlib import Path

from services.recorder.gaps import SeqGaps
from services.recorder.mcap_io import RecordingWriter


class Recorder:
    """Queue + writer of one recording.

    Args:
        path: output MCAP file.
        flush_period: how often the open chunk is closed and flushed [s].
        chunk_size: MCAP chunk size [bytes].
        compression: "zstd", "lz4" or "none".
    """

    def __init__(
        self, path: str | Path, flush_period: float = 0.2, chunk_size: int = 256 * 1024, compression: str = "zstd"
    ):
        self.writer = RecordingWriter(path, chunk_size=chunk_size, compression=compression)
        self.flush_period = flush_period
        self._queue: deque[tuple[str, bytes, int, int | None]] = deque()
        self._wake = threading.Event()
        self._count_lock = threading.Lock()
        self._last_flush = time.monotonic()
        self.received = 0
        self.max_queue = 0
        #: mocap frames lost on the bus before they reached us (seq gaps), which "written = received" cannot see
        self.gaps = SeqGaps()

    @property
    def written(self) -> int:
        return self.writer.written

    @property
    def queued(self) -> int:
        return len(self._queue)

    def on_message(self, key: str, payload: bytes, recv_ns: int | None = None, publish_ns: int | None = None) -> None:
        """Enqueue one received message (thread-safe, never blocks, never drops).

        Args:
            key: Zenoh key. payload: raw bytes.
            recv_ns: receive time [ns since epoch] (now when None).
            publish_ns: sender time [ns] if known (else derived from ``hdr.t0``).
        """
        # deque.append is atomic; the lock keeps the count exact if Zenoh calls from several threads.
        self._queue.append((key, payload, time.time_ns() if recv_ns is None else recv_ns, publish_ns))
        with self._count_lock:
            self.received += 1
        self._wake.set()

    def step(self, timeout: float = 0.05, max_items: int = 10_000) -> int:
        """Write queued messages (waiting up to ``timeout`` [s] for some); flush when due.

        Returns:
            number of messages written by this call.
        """
        if not self._queue:
            self._wake.wait(timeout)
            self._wake.clear()
        self.max_queue = max(self.max_queue, len(self._queue))
        n = 0
        while self._queue and n < max_items:
            key, payload, recv_ns, pub_ns = self._queue.popleft()
            self.writer.write(key, payload, recv_ns, pub_ns)
            self.gaps.step(key, payload)
            n += 1
        now = time.monotonic()
        if now - self._last_flush >= self.flush_period:
            self.writer.flush()
            self._last_flush = now
        return n

    def drain(self) -> None:
        """Write everything still queued and flush."""
        while self._queue:
            self.step(timeout=0)
        self.writer.flush()

    def close(self) -> dict[str, int]:
        """Drain, write the footer, close; returns the final counts."""
        self.drain()
        counts = {
            "received": self.received,
            "written": self.written,
            "max_queue": self.max_queue,
            "frames_missing": self.gaps.missing,
        }
        self.writer.close(summary={k: str(v) for k, v in counts.items()})
        return counts
