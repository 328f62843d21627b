"""Zenoh plumbing shared by every service.

* :func:`add_bus_args` / :func:`zenoh_config`: the common flags
  (``--mode --connect --listen --config --session``) and ``ZENOH_CONFIG``.
  Default: peer mode, multicast scouting off, connecting to the local router
  that ``mimic up`` starts on ``tcp/127.0.0.1:7447`` (``MIMIC_CONNECT``
  overrides it, as docker-compose does; ``MIMIC_MODE`` the mode: client in containers).
* :class:`ServiceRunner`: session, liveliness token, periodic
  :class:`~shared.messages.ServiceStatus`, SIGINT/SIGTERM handling.
* :class:`LatestSlot`: newest-sample-wins mailbox for streams where staleness
  matters (or a bounded queue with ``depth``); samples overwritten before being
  read are counted as dropped.
* :class:`NumberedPublisher`: every sample carries ``(publisher id, number)`` in
  its Zenoh attachment, so subscribers count the samples lost on the way (inside
  Zenoh under congestion, in a router) as ``gaps.<stream>`` in their status.

Congestion control is Zenoh's DROP for every stream: a real-time stream must never
stall its publisher (a blocked solver tick or mocap loop delays every later
message, which is worse than losing one), and what DROP loses is now counted by
the receiver's gap counter instead of vanishing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import socket
import struct
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import zenoh

from shared.keys import DEFAULT_SESSION, Keys
from shared.messages import MessageError, ServiceStatus
from shared.sequence import GapCounter

DEFAULT_ROUTER = "tcp/127.0.0.1:7447"
log = logging.getLogger("mimic.bus")


# --------------------------------------------------------------------------- configuration


def add_bus_args(parser: argparse.ArgumentParser) -> None:
    """Add the flags every service shares."""
    g = parser.add_argument_group("bus (Zenoh)")
    g.add_argument(
        "--session", default=os.environ.get("MIMIC_SESSION", DEFAULT_SESSION), help="key prefix mimic/<session>"
    )
    g.add_argument(
        "--mode",
        choices=("peer", "client", "router"),
        default=os.environ.get("MIMIC_MODE") or None,
        help="Zenoh mode (default $MIMIC_MODE or peer)",
    )
    g.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"endpoint to connect to, repeatable (default $MIMIC_CONNECT or {DEFAULT_ROUTER})",
    )
    g.add_argument(
        "--listen", action="append", default=None, metavar="ENDPOINT", help="endpoint to listen on, repeatable"
    )
    g.add_argument("--config", default=None, help="Zenoh JSON5 config file (default $ZENOH_CONFIG); flags override it")
    g.add_argument("--status-period", type=float, default=1.0, help="ServiceStatus period [s]")


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """Build the Zenoh config from a file (``--config`` / ``ZENOH_CONFIG``) and flags."""
    path = getattr(args, "config", None) or os.environ.get("ZENOH_CONFIG")
    if path:
        if not Path(path).exists():
            raise FileNotFoundError(f"Zenoh config {path} does not exist")
        conf = zenoh.Config.from_file(path)
    else:
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
    mode = getattr(args, "mode", None) or ("peer" if not path else None)
    if mode:
        conf.insert_json5("mode", json.dumps(mode))
    connect = getattr(args, "connect", None)
    if connect is None and not path:
        connect = [e for e in os.environ.get("MIMIC_CONNECT", DEFAULT_ROUTER).split(",") if e]
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    if json.loads(conf.get_json("mode") or "null") == "client" and conf.get_json("connect/timeout_ms") == "null":
        # A client cannot start without its router: wait for it (retrying) instead of failing, as
        # a container started beside the router's must. A lost router is reconnected to likewise.
        conf.insert_json5("connect/timeout_ms", "-1")
    listen = getattr(args, "listen", None)
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    elif not path and mode == "peer":
        # Peers listen on an ephemeral loopback port so gossip lets them reach each other directly.
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    return conf


def free_port() -> int:
    """A TCP port free on loopback right now (for routers and test endpoints)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_endpoint(endpoint: str, timeout: float) -> bool:
    """Wait until a TCP endpoint (``tcp/HOST:PORT``) accepts connections; False after ``timeout`` [s]."""
    host, port = endpoint.split("/", 1)[1].rsplit(":", 1)
    deadline = time.monotonic() + timeout
    while True:  # at least one try, so timeout 0 asks "is it listening now?"
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex((host, int(port))) == 0:
                return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.1)


def open_session(args: argparse.Namespace) -> zenoh.Session:
    """Open a Zenoh session configured from ``args``."""
    return zenoh.open(zenoh_config(args))


def bus_args(**overrides: Any) -> argparse.Namespace:
    """Namespace with the bus defaults, for code that opens a session without a CLI."""
    p = argparse.ArgumentParser()
    add_bus_args(p)
    ns = p.parse_args([])
    for k, v in overrides.items():
        setattr(ns, k, v)
    return ns


# --------------------------------------------------------------------------- status


class _Rate:
    """Messages per second over a sliding window."""

    def __init__(self, window: float = 2.0):
        self.window = window
        self.times: deque[float] = deque()

    def tick(self, now: float) -> None:
        self.times.append(now)

    def rate(self, now: float) -> float:
        while self.times and now - self.times[0] > self.window:
            self.times.popleft()
        return len(self.times) / self.window


class StatusCounters:
    """Thread-safe counters behind a service's ServiceStatus."""

    def __init__(self, service: str, instance: str, logger: logging.Logger):
        self.service = service
        self.instance = instance
        self.state = "ok"
        self.extra: dict[str, float] = {}
        self.start = time.monotonic()
        self._log = logger
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._rejects: dict[str, int] = {}
        self._outcomes: dict[str, int] = {}
        self._rates: dict[str, _Rate] = {}
        self._last_error = ""

    def _count(self, name: str, n: int = 1) -> None:
        """Add ``n`` to counter ``name``; the caller holds the lock."""
        self._counts[name] = self._counts.get(name, 0) + n

    def _stream(self, kind: str, stream: str, n: int = 1, rate: str | None = None) -> None:
        """Count ``n`` messages as ``kind`` in total and per stream (``kind.stream``); tick rate ``rate.stream``."""
        now = time.monotonic()
        with self._lock:
            self._count(kind, n)
            self._count(f"{kind}.{stream}", n)
            if rate is not None:
                self._rates.setdefault(f"{rate}.{stream}", _Rate()).tick(now)

    def received(self, stream: str) -> None:
        self._stream("received", stream, rate="in")

    def published(self, stream: str) -> None:
        self._stream("published", stream, rate="out")

    def outcome(self, name: str) -> None:
        """Count one result of the service's own work (e.g. a command's status), apart from messages."""
        with self._lock:
            self._outcomes[name] = self._outcomes.get(name, 0) + 1

    def dropped(self, stream: str, n: int = 1) -> None:
        """Count messages this service received and discarded on purpose (newest-wins, full queue)."""
        self._stream("dropped", stream, n)

    def gaps(self, stream: str, n: int) -> None:
        """Count messages that never arrived (publisher numbers skipped: lost in Zenoh or a router)."""
        self._stream("gaps", stream, n)

    def reject(self, reason: str, detail: str) -> None:
        """Count a rejected input; log the first of each reason (then every 1000th)."""
        with self._lock:
            k = self._rejects.get(reason, 0) + 1
            self._rejects[reason] = k
            self._count("rejected")
            self._last_error = f"{reason}: {detail}"[:1000]
        if k == 1 or k % 1000 == 0:
            self._log.warning("rejected input (%s, #%d): %s", reason, k, detail)

    def error(self, text: str) -> None:
        with self._lock:
            self._last_error = text[:1000]
            self._count("errors")
        self._log.error("%s", text)

    def count(self, name: str) -> int:
        with self._lock:
            return self._counts.get(name, 0)

    def snapshot(self) -> ServiceStatus:
        now = time.monotonic()
        with self._lock:
            return ServiceStatus(
                service=self.service,
                instance=self.instance,
                state=self.state,
                uptime=now - self.start,
                rates={k: r.rate(now) for k, r in self._rates.items()},
                counts=dict(self._counts),
                rejects=dict(self._rejects),
                last_error=self._last_error,
                extra=dict(self.extra),
                outcomes=dict(self._outcomes),
            )


# --------------------------------------------------------------------------- numbered samples

#: Attachment of a numbered sample: publisher id (u64), sample number (u64, from 1), little-endian.
_NUMBER = struct.Struct("<QQ")


class NumberedPublisher:
    """A Zenoh publisher whose samples carry ``(publisher id, number)`` in the attachment.

    The id is random per publisher (a restarted service is a new source); numbers count
    from 1. Subscribers feed them to a :class:`~shared.sequence.GapCounter`.
    Congestion control is DROP (see the module docstring).
    """

    def __init__(self, session: zenoh.Session, key: str, express: bool = True):
        self._pub = session.declare_publisher(key, express=express, congestion_control=zenoh.CongestionControl.DROP)
        self.source = int.from_bytes(os.urandom(8), "little")
        self.number = 0
        # put() inside the lock: two threads must not send numbers out of order.
        self._lock = threading.Lock()

    def put(self, payload: bytes) -> None:
        with self._lock:
            self.number += 1
            self._pub.put(payload, attachment=_NUMBER.pack(self.source, self.number))

    def undeclare(self) -> None:
        self._pub.undeclare()

    def __getattr__(self, name: str) -> Any:
        # Everything else (key_expr, matching_status, ...) is the Zenoh publisher's.
        if name == "_pub":  # not declared (the constructor failed): no recursion
            raise AttributeError(name)
        return getattr(self._pub, name)


def sample_number(sample: zenoh.Sample) -> tuple[int, int] | None:
    """``(publisher id, number)`` of a sample from a :class:`NumberedPublisher`; None for other publishers."""
    att = sample.attachment
    if att is None:
        return None
    raw = att.to_bytes()
    return _NUMBER.unpack(raw) if len(raw) == _NUMBER.size else None


def gap_watch(status: StatusCounters, stream: str) -> Callable[[zenoh.Sample], None]:
    """Sample hook counting lost samples of ``stream`` per publisher into ``status`` (``gaps.<stream>``)."""
    counter = GapCounter()

    def watch(sample: zenoh.Sample) -> None:
        num = sample_number(sample)
        if num is not None:
            gap = counter.see(*num)
            if gap:
                status.gaps(stream, gap)

    return watch


def guarded(
    handle: Callable[[zenoh.Sample], None], status: StatusCounters | None, name: str
) -> Callable[[zenoh.Sample], None]:
    """``handle`` that reports an exception to ``status`` instead of raising: a sample reader must
    outlive any bad sample."""

    def run(sample: zenoh.Sample) -> None:
        try:
            handle(sample)
        except Exception as exc:
            if status is not None:
                status.error(f"{name} receive failed: {type(exc).__name__}: {exc}")

    return run


def ring_pump(
    session: zenoh.Session,
    key: str,
    capacity: int,
    handle: Callable[[zenoh.Sample], None],
    status: StatusCounters | None = None,
    name: str = "ring",
) -> zenoh.Subscriber:
    """Subscribe ``key`` through a Rust-side ring of ``capacity`` samples drained by a thread calling ``handle``.

    Why not a plain callback: Zenoh calls a Python callback with the GIL for every sample, and
    while a worker holds the GIL the Zenoh thread waits (up to the switch interval each time), so
    a 10 kHz burst backed up in Zenoh and the kernel's TCP buffers (p99 1.6 s and growing) where
    newest-wins could not drop it. The ring drops its oldest without the GIL; those drops show
    up as gaps in a NumberedPublisher's numbering. The thread takes one sample blocking (GIL
    released), then all that are waiting without letting go: one hand-off per batch.

    The subscriber is not to be undeclared while the thread waits in ``recv()`` (zenoh-python
    1.10 fails with "Already borrowed"): closing the session ends ``recv()``, and the thread.
    A ``handle`` that raises is reported to ``status`` and the pump goes on.
    """
    sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
    handle = guarded(handle, status, name)

    def pump() -> None:
        while True:
            try:
                batch = [sub.recv()]
                while (more := sub.try_recv()) is not None:
                    batch.append(more)
            except zenoh.ZError:  # the session was closed
                return
            for sample in batch:
                handle(sample)

    threading.Thread(target=pump, name=f"{name}-rx", daemon=True).start()
    return sub


# --------------------------------------------------------------------------- mailboxes


class LatestSlot:
    """Keep only the newest ``depth`` messages (default 1: newest wins); count evicted ones as dropped.

    With ``max_age`` [s], a message that waited longer than that while newer ones
    arrived is stale: :meth:`take` skips it (counted as dropped), so a consumer that
    fell behind catches up with the newest at once instead of working through the
    queue (latency bounded by time, not by ``depth`` x its step time).

    With a ``decode`` function the slot stores raw payloads and decodes in
    :meth:`take`, i.e. in the consumer's thread: the receiving thread stays
    trivial. Payloads that fail to decode are counted as rejected.
    """

    def __init__(
        self,
        status: StatusCounters | None = None,
        stream: str = "",
        decode: Callable | None = None,
        depth: int = 1,
        max_age: float | None = None,
    ):
        self._cond = threading.Condition()
        self._items: deque[tuple[float, Any]] = deque()  # (arrival, monotonic [s]; message)
        self._depth = max(1, int(depth))
        self._max_age = max_age
        self._status = status
        self._stream = stream
        self._decode = decode

    def _drop(self) -> None:
        self._items.popleft()
        if self._status is not None:
            self._status.dropped(self._stream)

    def put(self, msg: Any) -> None:
        with self._cond:
            if len(self._items) >= self._depth:
                self._drop()
            self._items.append((time.monotonic(), msg))
            self._cond.notify_all()

    def pending(self) -> int:
        """Messages waiting to be taken."""
        with self._cond:
            return len(self._items)

    def take(self, timeout: float | None = None) -> Any:
        """Oldest kept unread message that is not stale, waiting up to ``timeout`` [s]; None if none arrived
        (or it was invalid)."""
        with self._cond:
            if not self._items and timeout:
                self._cond.wait(timeout)
            if not self._items:
                return None
            if self._max_age is not None:
                oldest_fresh = time.monotonic() - self._max_age
                while len(self._items) > 1 and self._items[0][0] < oldest_fresh:
                    self._drop()
            raw = self._items.popleft()[1]
        if self._decode is None:
            return raw
        try:
            msg = self._decode(raw)
        except MessageError as exc:
            if self._status is not None:
                self._status.reject(exc.reason, f"{self._stream}: {exc.detail}")
            return None
        except Exception as exc:  # a decoder bug must not kill the consumer
            if self._status is not None:
                self._status.reject("decoder", f"{self._stream}: {type(exc).__name__}: {exc}")
            return None
        return msg


#: How often :meth:`RingReader.take` looks at the ring while it waits with a timeout [s] (start-up only).
RING_POLL_S = 0.005


class RingReader:
    """A consumer that reads its subscription's Rust-side ring itself: no receiver thread.

    Samples go through ``on_sample`` into ``slot`` (a :class:`LatestSlot`: depth, age and
    decoding as there) only when the consumer asks, in its own thread. Compared with
    :func:`ring_pump` each sample skips a thread hand-off: no wake-up of a receiver thread and no
    GIL switch against the busy consumer. Two ways to ask:

    * :meth:`wait_take` blocks in the ring's ``recv()`` (GIL released) until a message comes: for
      a consumer without deadlines (the retarget's worker);
    * :meth:`take` drains what is waiting now, without blocking: for a consumer that only needs
      the newest sample at its own tick (the solver's robot state). No thread ever wakes for it.

    The ring's own overflow (oldest first, without the GIL) shows up as gaps in a
    NumberedPublisher's numbers. ``recv()`` has no timeout in zenoh-python 1.10: :meth:`wait_take`
    returns None when the session is closed (the consumer's way out), and the subscriber must not
    be undeclared while it waits.
    """

    def __init__(
        self,
        sub: zenoh.Subscriber,
        on_sample: Callable[[zenoh.Sample], None],
        slot: LatestSlot,
        status: StatusCounters | None = None,
        name: str = "ring",
    ):
        self._sub = sub
        self._handle = guarded(on_sample, status, name)
        self.slot = slot
        self.closed = False

    def _drain(self) -> None:
        try:
            while (sample := self._sub.try_recv()) is not None:
                self._handle(sample)
        except zenoh.ZError:  # the session was closed
            self.closed = True

    def take(self, timeout: float | None = None) -> Any:
        """Like :meth:`LatestSlot.take`: the next message waiting now, or None. With ``timeout`` [s]
        it looks again every RING_POLL_S until one comes (meant for start-up waits, not hot paths)."""
        deadline = time.monotonic() + (timeout or 0.0)
        while True:
            self._drain()
            if self.slot.pending() or self.closed or time.monotonic() >= deadline:
                return self.slot.take()
            time.sleep(RING_POLL_S)

    def wait_take(self) -> Any:
        """The next message, waiting as long as it takes; None when the session closed, or when what
        came was invalid (see :class:`LatestSlot`)."""
        while not self.slot.pending():
            try:
                sample = self._sub.recv()
            except zenoh.ZError:  # the session was closed
                self.closed = True
                return None
            self._handle(sample)
        self._drain()
        return self.slot.take()


# --------------------------------------------------------------------------- runner


#: Smallest Rust-side ring a newest-wins subscription keeps before its Python mailbox [samples].
RING_MIN_CAPACITY = 8
#: CPython thread switch interval for services [s] (default 5 ms).
SWITCH_INTERVAL_S = 5e-4


class ServiceRunner:
    """Lifecycle of one service process on the bus.

    Opens the session, declares the liveliness token
    ``mimic/<session>/alive/<service>/<instance>``, publishes ServiceStatus on
    ``mimic/<session>/<service>/status`` every ``--status-period`` seconds, and
    turns SIGINT/SIGTERM into :attr:`stop_event`. Use as a context manager; on
    exit everything is undeclared and the session closed.
    """

    def __init__(self, service: str, args: argparse.Namespace, instance: str = "main", install_signals: bool = True):
        self.service = service
        self.instance = instance
        self.args = args
        self.keys = Keys(getattr(args, "session", DEFAULT_SESSION))
        self.log = logging.getLogger(f"mimic.{service}")
        self.status = StatusCounters(service, instance, self.log)
        self.stop_event = threading.Event()
        self._install_signals = install_signals
        self._entities: list[Any] = []
        self._status_thread: threading.Thread | None = None
        self.session: zenoh.Session | None = None
        #: Called right before each status is published (a service's own figures and state), so a
        #: status never pairs fresh counts with a stale state.
        self.before_status: Callable[[], None] | None = None

    # lifecycle
    def __enter__(self) -> ServiceRunner:
        # Zenoh delivers samples on its own threads, which need the GIL for a moment each. With
        # CPython's default 5 ms switch interval a busy worker thread (retarget, solver, sim) keeps
        # them waiting up to 5 ms per sample, so under load samples back up inside Zenoh and the
        # kernel where newest-wins cannot drop them. 0.5 ms keeps the hand-off latency small.
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        if self._install_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, self._on_signal)
        self.session = open_session(self.args)
        self._entities.append(self.session.liveliness().declare_token(self.keys.alive(self.service, self.instance)))
        self._status_pub = self.publisher(
            self.keys.status(self.service, self.instance if self.instance != "main" else None)
        )
        self._status_thread = threading.Thread(target=self._status_loop, name=f"{self.service}-status", daemon=True)
        self._status_thread.start()
        self.log.info("%s/%s up on session %s", self.service, self.instance, self.keys.session)
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop_event.set()
        if self._status_thread is not None:
            self._status_thread.join(timeout=2.0)
        self._refresh_status()  # the last figures, then "stopping" (a refresh would say "ok" again)
        self.status.state = "stopping"
        try:
            self._publish_status(refresh=False)
        except Exception:  # the session may already be unusable at exit
            pass
        for ent in reversed(self._entities):
            try:
                ent.undeclare()
            except Exception:
                pass
        if self.session is not None:
            self.session.close()
        self.log.info("%s/%s stopped", self.service, self.instance)

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self.log.info("signal %d: stopping", signum)
        self.stop_event.set()

    def wait(self) -> None:
        """Block until SIGINT/SIGTERM (or :attr:`stop_event` is set)."""
        while not self.stop_event.wait(0.2):
            pass

    def _refresh_status(self) -> None:
        if self.before_status is not None:
            try:
                self.before_status()
            except Exception as exc:  # status must never take the service down
                self.log.debug("status update failed: %s", exc)

    def _publish_status(self, refresh: bool = True) -> None:
        if refresh:
            self._refresh_status()
        self._status_pub.put(self.status.snapshot().encode())

    def _status_loop(self) -> None:
        period = max(0.05, float(getattr(self.args, "status_period", 1.0)))
        while not self.stop_event.wait(period):
            try:
                self._publish_status()
            except Exception as exc:  # status must never take the service down
                self.log.debug("status publish failed: %s", exc)

    # helpers
    def publisher(self, key: str, express: bool = True) -> NumberedPublisher:
        """Declare a numbered publisher; ``express`` skips batching for lowest latency."""
        pub = NumberedPublisher(self.session, key, express=express)
        self._entities.append(pub)
        return pub

    def publish(self, pub: NumberedPublisher, msg: Any, stream: str) -> None:
        """Encode a message, put it, count it."""
        pub.put(msg.encode())
        self.status.published(stream)

    def _decoding(self, decode: Callable[[bytes], Any], stream: str, sink: Callable[[Any], None]):
        status = self.status
        watch = gap_watch(status, stream)

        def on_sample(sample: zenoh.Sample) -> None:
            watch(sample)
            try:
                msg = decode(sample.payload.to_bytes())
            except MessageError as exc:
                status.reject(exc.reason, f"{stream}: {exc.detail}")
                return
            except Exception as exc:  # a decoder bug must not kill the subscriber thread
                status.reject("decoder", f"{stream}: {type(exc).__name__}: {exc}")
                return
            status.received(stream)
            try:
                sink(msg)
            except Exception as exc:
                status.error(f"{stream} handler failed: {type(exc).__name__}: {exc}")

        return on_sample

    def subscribe(self, key: str, callback: Callable[[Any], None], decode: Callable[[bytes], Any], stream: str):
        """Every sample on ``key``, decoded; bad payloads rejected and counted."""
        sub = self.session.declare_subscriber(key, self._decoding(decode, stream, callback))
        self._entities.append(sub)
        return sub

    def _into_slot(
        self, slot: LatestSlot, stream: str, accept: Callable[[str], bool] | None
    ) -> Callable[[zenoh.Sample], None]:
        """Per-sample bookkeeping of a mailbox subscription: gaps, ``accept`` filter, received, raw payload in."""
        status = self.status
        watch = gap_watch(status, stream)

        def on_sample(sample: zenoh.Sample) -> None:
            watch(sample)
            if accept is not None and not accept(str(sample.key_expr)):
                return
            status.received(stream)
            slot.put(sample.payload.to_bytes())

        return on_sample

    def subscribe_latest(
        self,
        key: str,
        decode: Callable[[bytes], Any],
        stream: str,
        depth: int = 1,
        accept: Callable[[str], bool] | None = None,
        max_age: float | None = None,
    ) -> LatestSlot:
        """Newest-wins mailbox (keeping ``depth`` messages) fed by a subscriber on ``key``.

        Payloads are decoded by ``take()`` in the consumer's thread, once, and only if
        taken. Zenoh's own thread never takes the GIL: it fills a ring of at least
        RING_MIN_CAPACITY samples that a receiver thread drains into the mailbox.
        ``accept(sample key)`` filters samples before they count as received (e.g. the
        sim keeps only the followed solver's commands); lost samples count as gaps either way.
        ``max_age`` [s]: see :class:`LatestSlot`.
        """
        slot = LatestSlot(self.status, stream, decode, depth, max_age)
        on_sample = self._into_slot(slot, stream, accept)
        ring_pump(self.session, key, max(depth, RING_MIN_CAPACITY), on_sample, self.status, f"{self.service}-{stream}")
        return slot

    def subscribe_reader(
        self,
        key: str,
        decode: Callable[[bytes], Any],
        stream: str,
        depth: int = 1,
        max_age: float | None = None,
        ring: int | None = None,
    ) -> RingReader:
        """Like :meth:`subscribe_latest`, without the receiver thread: the consumer reads the ring
        itself (:class:`RingReader`: waiting without a deadline, or polling at its own tick).

        ``ring``: samples the Rust-side ring keeps while the consumer is busy (default ``depth``, at
        least RING_MIN_CAPACITY). Nothing moves them into the mailbox meanwhile, so a consumer that
        must not lose samples to a stall gives it room for the longest stall it absorbs.
        """
        slot = LatestSlot(self.status, stream, decode, depth, max_age)
        capacity = ring if ring is not None else max(depth, RING_MIN_CAPACITY)
        sub = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
        # Not in _entities: undeclaring while take() waits in recv() fails; closing the session ends it.
        return RingReader(sub, self._into_slot(slot, stream, None), slot, self.status, f"{self.service}-{stream}")

    def queryable(self, key: str, handler: Callable[[bytes | None], bytes]):
        """Serve ``key``: ``handler(payload or None) -> reply bytes``; exceptions become error replies."""

        def on_query(query: zenoh.Query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else None
            try:
                query.reply(key, handler(payload))
            except Exception as exc:
                self.status.reject("query", f"{key}: {exc}")
                query.reply_err(f"{type(exc).__name__}: {exc}".encode())

        q = self.session.declare_queryable(key, on_query)
        self._entities.append(q)
        return q


def query(session: zenoh.Session, key: str, payload: bytes | None = None, timeout: float = 2.0) -> bytes:
    """One request/reply on a queryable; raises RuntimeError on error or no reply."""
    replies = session.get(key, payload=payload, timeout=timeout)
    for reply in replies:
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
        raise RuntimeError(f"query {key} failed: {reply.err.payload.to_bytes().decode(errors='replace')}")
    raise RuntimeError(f"query {key}: no reply within {timeout} s")


def query_when_ready(session: zenoh.Session, key: str, timeout: float = 3.0, interval: float = 0.3) -> bytes:
    """GET ``key`` again every ``interval`` [s] until it answers or ``timeout`` [s] passes.

    A session opened a moment ago may not know the route to the queryable yet, so a one-shot
    command line tool would report "no reply" from a healthy stack. Raises RuntimeError like
    :func:`query` (its last error).
    """
    deadline = time.monotonic() + timeout
    while True:
        try:
            return query(session, key, None, timeout=min(interval, max(0.05, deadline - time.monotonic())))
        except RuntimeError as exc:
            if "no reply" not in str(exc) or time.monotonic() >= deadline:
                raise


class StackAbsentError(RuntimeError):
    """A control command found nobody serving the queryable it talks to (message: one line)."""


@contextlib.contextmanager
def control_session(
    args: argparse.Namespace, key: str, timeout: float, who: str
) -> Iterator[tuple[zenoh.Session, bytes]]:
    """A control command's session and the current state served on ``key`` (GET, retried until routed).

    Args:
        args: bus arguments (``add_bus_args``). who: what serves ``key``, for the error ("no sim").
    Raises:
        StackAbsentError: nothing answered within ``timeout`` [s]; says who, the session and what to check.
    """
    with open_session(args) as z:
        try:
            state = query_when_ready(z, key, timeout)
        except RuntimeError as exc:
            raise StackAbsentError(f"{who} answered on session {args.session!r} ({exc})") from None
        yield z, state


def setup_logging(level: str | int = "INFO", prefix: str = "") -> None:
    """Process-wide logging format; ``MIMIC_LOG`` overrides the level."""
    level = os.environ.get("MIMIC_LOG", level)
    fmt = f"%(asctime)s %(levelname).1s {prefix}%(name)s: %(message)s"
    logging.basicConfig(level=level, format=fmt, force=True)
