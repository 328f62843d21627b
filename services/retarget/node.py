"""Bus wiring of the retarget service: mocap frames in, task targets out.

Subscribes HumanFrames on ``keys.mocap_frame`` (decoding and retargeting one frame costs
~0.7 ms; a queue absorbs stalls, and frames gone stale behind newer ones are skipped and counted),
publishes TaskTargets on ``keys.targets``, and
serves three queryables:

* ``keys.calibration``: GET without payload returns the current calibration (msgpack
  map, see :meth:`Calibration.to_dict`; ``{"calibrated": false}`` before any). A
  payload (msgpack or JSON map) installs a new calibration and returns it; the
  payload ``{"action": "recalibrate"}`` re-runs the anthropometric calibration on the
  next usable frame (operator at rest).
* ``keys.config("retarget")``: GET returns the configuration and workspace box.
* ``keys.retarget_source``: GET returns ``{"follow", "chosen", "sources"}`` (the source
  followed now, the one chosen explicitly or null, frames received per source); a payload (a
  source name, or ``{"source": NAME}``; empty name: none chosen) chooses the source to follow.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path

import msgpack
import numpy as np

from services.retarget.calibration import Calibration, CalibrationError
from services.retarget.retargeter import Retargeter
from shared.bus import ServiceRunner
from shared.messages import HumanFrame, MessageError, parse_query

#: Frames kept waiting for the worker before the oldest is skipped (absorbs a stall: 0.27 s at 120 Hz).
FRAME_QUEUE = 32
#: A frame that waited longer than this [s] while newer ones arrived is skipped (counted as dropped):
#: the solver only takes the newest target, so working through stale frames only adds latency
#: (a 32-deep queue alone gave ~200 ms under a 10 kHz burst on 2 cores).
FRAME_MAX_AGE = 0.1
#: Frames the Zenoh ring keeps while the worker is busy (it drains them into the queue only between
#: steps): a stall of 2 s at 120 Hz, 0.25 s at 1 kHz loses nothing; what waited too long is then
#: skipped by FRAME_MAX_AGE and counted, and only beyond this are frames lost (counted as gaps).
FRAME_RING = 256
#: While frames are rejected as uncalibrated, say so (log warning) at most this often [s].
UNCALIBRATED_LOG_PERIOD = 2.0


def _decode_map(payload: bytes) -> dict:
    try:
        d = parse_query(payload)
    except MessageError as exc:
        raise CalibrationError(f"calibration payload: {exc.detail}") from None
    if not isinstance(d, dict):
        raise CalibrationError(f"calibration payload must be a map, got {type(d).__name__}")
    return d


class RetargetNode:
    """Glue between a :class:`Retargeter` and a :class:`ServiceRunner`.

    Args:
        retargeter: the pure logic.
        svc: an entered ServiceRunner.
        save_calibration: files every new calibration (auto or set) is written to (may be empty).
    """

    def __init__(self, retargeter: Retargeter, svc: ServiceRunner, save_calibration: Sequence[Path] = ()):
        self.retargeter = retargeter
        self.svc = svc
        self.save_calibration = list(save_calibration)
        self._lock = threading.Lock()
        self._step_us: deque[float] = deque(maxlen=2000)
        self._uncalibrated = 0  # frames rejected as uncalibrated since the last warning
        self._uncalibrated_logged = -float("inf")  # monotonic time of that warning [s]
        self._calibration_seen = retargeter.calibration
        self._pub = svc.publisher(svc.keys.targets)
        # Every frame is retargeted while we keep up; under overload (bursts faster than we can
        # retarget) stale frames are skipped and counted, so latency stays bounded.
        # The worker reads the frames' ring itself (one thread hand-off less per frame than a mailbox
        # fed by a receiver thread): it has no deadline to keep, so a blocking wait is all it needs.
        self.frames = svc.subscribe_reader(
            svc.keys.mocap_frame,
            HumanFrame.decode,
            stream="frames",
            depth=FRAME_QUEUE,
            max_age=FRAME_MAX_AGE,
            ring=FRAME_RING,
        )
        self._worker = threading.Thread(target=self._spin, name="retarget-worker", daemon=True)
        self._worker.start()
        svc.queryable(svc.keys.calibration, self.on_calibration)
        svc.queryable(svc.keys.config("retarget"), self.on_config)
        svc.queryable(svc.keys.retarget_source, self.on_source)

    def _spin(self) -> None:
        while not self.svc.stop_event.is_set() and not self.frames.closed:
            frame = self.frames.wait_take()
            if frame is not None:
                self.on_frame(frame)

    def on_frame(self, frame: HumanFrame) -> None:
        """Retarget and publish one frame; rejects are counted in the status."""
        t = time.perf_counter()
        with self._lock:
            out = self.retargeter.step(frame)
            reject = self.retargeter.last_reject
            cal = self.retargeter.calibration
        self._step_us.append((time.perf_counter() - t) * 1e6)
        if cal is not self._calibration_seen:
            self._calibration_seen = cal
            self._on_new_calibration(cal)
        if out is None:
            if reject is not None:
                self.svc.status.reject(*reject)
                if reject[0] == "uncalibrated":
                    self._warn_uncalibrated(reject[1])
            return
        self.svc.publish(self._pub, out, stream="targets")

    def _warn_uncalibrated(self, detail: str) -> None:
        """Repeat, every UNCALIBRATED_LOG_PERIOD, that frames are being thrown away and why: a user
        plugging in a source must not have to find the one warning of the first reject."""
        self._uncalibrated += 1
        now = time.monotonic()
        if now - self._uncalibrated_logged >= UNCALIBRATED_LOG_PERIOD:
            self.svc.log.warning("%d frame(s) rejected, not calibrated: %s", self._uncalibrated, detail)
            self._uncalibrated, self._uncalibrated_logged = 0, now

    def _on_new_calibration(self, cal: Calibration | None) -> None:
        if cal is None:
            return
        self.svc.log.info(
            "calibration %s: rest %s", cal.source, {t: np.round(p, 3).tolist() for t, p in cal.rest.items()}
        )
        for path in self.save_calibration:
            try:
                cal.save(path)
            except OSError as exc:
                self.svc.status.error(f"cannot save calibration to {path}: {exc}")

    def on_calibration(self, payload: bytes | None) -> bytes:
        """Queryable handler: GET returns the calibration, a payload sets it (see module doc)."""
        if payload:
            d = _decode_map(payload)
            if d.get("action") == "recalibrate":
                with self._lock:
                    self.retargeter.request_recalibration()
                return msgpack.packb({"calibrated": self.retargeter.calibration is not None, "pending": True})
            cal = Calibration.from_dict(d)
            if cal.source == "manual":
                cal.source = "query"
            with self._lock:
                self.retargeter.set_calibration(cal)
            self._calibration_seen = cal
            self._on_new_calibration(cal)
        with self._lock:
            cal = self.retargeter.calibration
        if cal is None:
            return msgpack.packb({"calibrated": False})
        return msgpack.packb({"calibrated": True, **cal.to_dict()})

    def on_source(self, payload: bytes | None) -> bytes:
        """Queryable handler: GET the followed source, a payload chooses it (see module doc)."""
        if payload:
            d = parse_query(payload)
            name = d.get("source") if isinstance(d, dict) else d
            if not isinstance(name, str):
                raise ValueError(f"source payload: expected a name or {{'source': NAME}}, got {d!r}")
            with self._lock:
                self.retargeter.follow_source(name)
            self.svc.log.info(
                "source chosen by query: %s", repr(name) if name else "none (the first one seen is followed)"
            )
        with self._lock:
            r = self.retargeter
            return msgpack.packb(
                {"follow": r.followed_source, "chosen": r.config.source or None, "sources": dict(r.sources_seen)}
            )

    def on_config(self, payload: bytes | None) -> bytes:
        """Queryable handler: the configuration and workspace box (read-only)."""
        if payload:
            raise ValueError("retarget config is read-only at run time; restart with other flags")
        return msgpack.packb(
            {"config": self.retargeter.config.to_dict(), "workspace": self.retargeter.workspace.summary()}
        )

    def update_status(self) -> None:
        """Refresh the service-specific status figures."""
        st = self.svc.status
        if self._step_us:
            us = np.asarray(self._step_us)
            st.extra["step_us_p50"] = float(np.percentile(us, 50))
            st.extra["step_us_p99"] = float(np.percentile(us, 99))
        with self._lock:  # step() may add counters concurrently
            counts = dict(self.retargeter.counts)
            calibrated = self.retargeter.calibration is not None
        for k, v in counts.items():
            st.extra[k] = float(v)
        st.extra["calibrated"] = 1.0 if calibrated else 0.0
        st.state = "ok" if calibrated else "degraded"


def run(args, retargeter: Retargeter, save_calibration: Sequence[Path] = ()) -> int:
    """Run the service until SIGINT/SIGTERM."""
    with ServiceRunner("retarget", args) as svc:
        node = RetargetNode(retargeter, svc, save_calibration)
        node.update_status()
        svc.before_status = node.update_status
        svc.log.info(
            "retargeting %s -> %s, mode %s, calibration %s",
            svc.keys.mocap_frame,
            svc.keys.targets,
            retargeter.config.mode,
            retargeter.calibration.source if retargeter.calibration else "auto (first rest frame)",
        )
        svc.wait()
    return 0
