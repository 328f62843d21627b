"""``mimic ingest``: live HumanFrame sources onto ``mimic/<s>/mocap/frame``.

``--udp HOST:PORT`` accepts HumanFrame msgpack datagrams (the bus contract);
``--xsens HOST:PORT`` accepts Xsens MVN network streaming (type 02). Both bind
127.0.0.1 unless a host is given. Every frame passes the sanitizer; drops and
invalidations are counted with ``status.reject(reason)``, repairs in
``status.extra["repaired.<reason>"]``, each reason logged once.
"""

from __future__ import annotations

import argparse
import logging
import selectors
import socket
import threading
import time

from services.ingest.live import LiveIngest
from services.ingest.xsens import MvnDecoder
from shared.bus import ServiceRunner, add_bus_args
from shared.report import emit_json

DEFAULT_HOST = "127.0.0.1"
log = logging.getLogger("mimic.ingest")


def parse_endpoint(text: str, default_port: int | None = None) -> tuple[str, int]:
    """``"HOST:PORT"``, ``":PORT"`` or ``"PORT"`` -> (host, port); host defaults to loopback."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "", text
    try:
        p = int(port) if port else default_port
    except ValueError:
        raise ValueError(f"bad endpoint {text!r}: port must be an integer (HOST:PORT)") from None
    if p is None or not 0 <= p <= 65535:
        raise ValueError(f"bad endpoint {text!r}: port out of range")
    return host.strip("[]") or DEFAULT_HOST, p


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--udp", default=None, metavar="HOST:PORT", help="HumanFrame msgpack datagrams (e.g. :9870)")
    parser.add_argument("--xsens", default=None, metavar="HOST:PORT", help="Xsens MVN streaming (MVN default :9763)")
    parser.add_argument("--xsens-units", default="cm", choices=("cm", "m"), help="MVN position unit (spec: cm)")
    parser.add_argument("--xsens-character", type=int, default=None, help="only this MVN character id")
    parser.add_argument("--restamp", action="store_true", help="set hdr.t0 at receipt instead of trusting the sender")
    parser.add_argument("--instance", default="main", help="status instance name")
    add_bus_args(parser)


def _open(host: str, port: int) -> socket.socket:
    s = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    s.bind((host, port))
    s.setblocking(False)
    return s


def run(
    args: argparse.Namespace, stop_event: threading.Event | None = None, ready: threading.Event | None = None
) -> dict:
    """Serve until stopped; returns the final counts."""
    if not args.udp and not args.xsens:
        raise ValueError("nothing to ingest: give --udp HOST:PORT and/or --xsens HOST:PORT")
    core = LiveIngest(MvnDecoder(args.xsens_units, args.xsens_character), restamp=args.restamp)
    sel = selectors.DefaultSelector()
    socks = []
    for source, ep in (("udp", args.udp), ("xsens", args.xsens)):
        if ep:
            host, port = parse_endpoint(ep)
            s = _open(host, port)
            socks.append(s)
            sel.register(s, selectors.EVENT_READ, source)
            log.info("listening for %s datagrams on %s:%d", source, host, s.getsockname()[1])
    repaired: dict[str, int] = {}
    try:
        with ServiceRunner("ingest", args, instance=args.instance) as svc:
            stop = stop_event or svc.stop_event
            pub = svc.publisher(svc.keys.mocap_frame)
            if ready is not None:
                ready.set()
            while not stop.is_set():
                for key, _ in sel.select(timeout=0.1):
                    while True:
                        try:
                            data = key.fileobj.recv(65535)
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError as exc:
                            svc.status.error(f"{key.data} socket: {exc}")
                            break
                        svc.status.received(key.data)
                        frame, issues = core.step(key.data, data, time.time_ns())
                        for i in issues:
                            if i.action == "repaired":
                                n = repaired.get(i.reason, 0) + 1
                                repaired[i.reason] = n
                                svc.status.extra[f"repaired.{i.reason}"] = n
                                if n == 1:
                                    svc.log.warning("repaired input (%s): %s", i.reason, i.detail)
                            else:
                                svc.status.reject(i.reason, i.detail)
                        if frame is not None:
                            svc.publish(pub, frame, stream="frames")
            snap = svc.status.snapshot()
    finally:
        for s in socks:
            sel.unregister(s)
            s.close()
        sel.close()
    return {"counts": snap.counts, "rejects": snap.rejects, "repaired": repaired}


def main(args: argparse.Namespace) -> int:
    try:
        summary = run(args)
    except (ValueError, OSError) as exc:
        log.error("%s", exc)
        return 2
    emit_json(summary, indent=None)
    return 0
