"""Bus wiring of the logger: every sample of the session into Rerun, off the zenoh thread.

The zenoh callback only timestamps the sample and puts it in a bounded queue
(``put_nowait``); one worker thread runs :meth:`RerunLogger.step`. When the queue is
full the sample is skipped and counted (``dropped.messages`` in the status and the
``metrics/logger/skipped`` series), so a slow logger never slows the stack down.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque

import numpy as np
import zenoh

from services.logger.rerun_logger import RerunLogger
from shared.bus import ServiceRunner


class LoggerNode:
    """Queue + worker thread in front of a :class:`RerunLogger`.

    Args:
        logger: the pure translator.
        svc: an entered ServiceRunner (its session subscribes ``keys.everything``).
        queue_size: samples buffered before new ones are skipped.
    """

    def __init__(self, logger: RerunLogger, svc: ServiceRunner, queue_size: int = 4096):
        self.logger = logger
        self.svc = svc
        self.queue: queue.Queue[tuple[str, bytes, int] | None] = queue.Queue(maxsize=queue_size)
        self.skipped = 0
        self._skipped_logged = 0
        self._step_us: deque[float] = deque(maxlen=4000)
        self._worker = threading.Thread(target=self._work, name="log-worker", daemon=True)
        self._worker.start()
        self._sub = svc.session.declare_subscriber(svc.keys.everything, self.on_sample)

    def on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh callback: enqueue, never block."""
        try:
            self.queue.put_nowait((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))
        except queue.Full:
            self.skipped += 1
            self.svc.status.dropped("messages")
            return
        self.svc.status.received("messages")

    def _work(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            t = time.perf_counter()
            try:
                self.logger.step(*item)
            except Exception as exc:  # one bad sample must not stop the recording
                self.svc.status.error(f"logging {item[0]} failed: {type(exc).__name__}: {exc}")
            self._step_us.append((time.perf_counter() - t) * 1e6)
            if self.skipped != self._skipped_logged:
                self._skipped_logged = self.skipped
                self.logger.log_skipped(self.skipped)

    def update_status(self) -> None:
        """Refresh the service-specific status figures.

        Called from the status thread right before each status is published, while the worker
        logs: the worker's dicts and deque are copied first (one C-level copy each, atomic under
        the GIL) so a key added meanwhile cannot break the iteration.
        """
        st = self.svc.status
        st.extra["queue"] = float(self.queue.qsize())
        st.extra["skipped"] = float(self.skipped)
        for k, v in dict(self.logger.counts).items():
            st.extra[f"logged.{k}"] = float(v)
        st.extra["rejected"] = float(sum(dict(self.logger.rejects).values()))
        steps = list(self._step_us)
        if steps:
            us = np.asarray(steps)
            st.extra["step_us_p50"] = float(np.percentile(us, 50))
            st.extra["step_us_p99"] = float(np.percentile(us, 99))
        st.state = "degraded" if self.skipped else "ok"

    def close(self, drain_timeout: float = 10.0) -> None:
        """Stop listening, log what is still queued (up to ``drain_timeout`` [s]), stop the worker."""
        try:
            self._sub.undeclare()
        except Exception:
            pass
        deadline = time.monotonic() + drain_timeout
        while not self.queue.empty() and time.monotonic() < deadline:
            time.sleep(0.02)
        try:
            self.queue.put(None, timeout=max(0.1, deadline - time.monotonic()))
        except queue.Full:
            pass
        self._worker.join(timeout=max(0.1, deadline - time.monotonic()))
