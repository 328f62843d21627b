"""``mimic calibrate``: see, set or redo the operator calibration of a running retarget.

Talks to retarget's calibration queryable (``keys.calibration``):

* no option: prints ``{"calibrated": ..., "source": ...}`` as JSON;
* ``--recalibrate``: the next frame with both arms' shoulder, elbow and wrist (the operator at
  rest, arms hanging) becomes the calibration;
* ``--file FILE``: installs a calibration file (JSON/TOML, e.g. from
  ``mimic retarget-plot CLIP --calibrate clip --write-calibration FILE``).

Exit status 1 with a one-line error when no retarget answers on the session.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import msgpack

from services.retarget.calibration import Calibration, CalibrationError
from shared.bus import add_bus_args, open_session, query, query_when_ready
from shared.keys import Keys

log = logging.getLogger("mimic.calibrate")


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--recalibrate", action="store_true", help="calibrate again from the next rest frame")
    g.add_argument("--file", type=Path, default=None, help="install this calibration file (JSON or TOML)")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for retarget's answer")
    add_bus_args(p)


def main(args: argparse.Namespace) -> int:
    if args.file is not None:
        try:
            payload = msgpack.packb(Calibration.load(args.file).to_dict())
        except (OSError, CalibrationError) as exc:
            log.error("cannot read calibration %s: %s", args.file, exc)
            return 1
    elif args.recalibrate:
        payload = msgpack.packb({"action": "recalibrate"})
    else:
        payload = None
    key = Keys(args.session).calibration
    with open_session(args) as z:
        try:
            reply = msgpack.unpackb(query_when_ready(z, key, args.timeout))  # GET: the route is known
            if payload is not None:
                reply = msgpack.unpackb(query(z, key, payload, timeout=args.timeout))
        except RuntimeError as exc:
            log.error(
                "no retarget answered on session %r (%s): is the stack up on this endpoint/session?", args.session, exc
            )
            return 1
    print(json.dumps({k: reply[k] for k in ("calibrated", "pending", "source") if k in reply}))
    return 0
