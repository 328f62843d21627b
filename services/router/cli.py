"""``mimic router``: a Zenoh router that the local services connect to.

The Python Zenoh package embeds the full router, so the embedded stack needs
no separate ``zenohd`` binary; docker-compose runs the same command.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import threading

import zenoh

from shared.bus import DEFAULT_ROUTER

log = logging.getLogger("mimic.router")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"endpoint to listen on, repeatable (default $MIMIC_ROUTER_LISTEN or {DEFAULT_ROUTER})",
    )
    p.add_argument("--config", default=None, help="Zenoh router JSON5 config (e.g. deploy/zenoh-router.json5)")


def router_config(listen: list[str] | None, config: str | None) -> zenoh.Config:
    """Router config: from file when given, else loopback listen with multicast scouting off."""
    conf = zenoh.Config.from_file(config) if config else zenoh.Config()
    conf.insert_json5("mode", '"router"')
    if not config:
        conf.insert_json5("scouting/multicast/enabled", "false")
    if listen or not config:
        conf.insert_json5("listen/endpoints", json.dumps(listen or [DEFAULT_ROUTER]))
    return conf


def main(args: argparse.Namespace) -> int:
    if args.listen is None and os.environ.get("MIMIC_ROUTER_LISTEN"):
        args.listen = os.environ["MIMIC_ROUTER_LISTEN"].split(",")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with zenoh.open(router_config(args.listen, args.config)) as session:
        log.info("router %s listening on %s", session.info.zid(), args.listen or [DEFAULT_ROUTER])
        while not stop.wait(0.5):
            pass
    log.info("router stopped")
    return 0
