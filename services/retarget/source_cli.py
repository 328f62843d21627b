"""``mimic source [NAME | --auto]``: which mocap source the running retarget follows, or choose it.

Talks to retarget's source queryable (``keys.retarget_source``). With two sources publishing on
a session, retarget follows one: the first seen (until it is silent for ``--source-timeout``),
or the one chosen here (or with ``mimic retarget --source NAME``); frames of the others are
rejected as ``other_source``. Choosing a source no frame has come from yet is refused in one
line, unless ``--force`` (a source about to start). ``--auto`` drops the choice.

Prints ``{"follow", "chosen", "was", "sources"}`` as JSON; exit status 1 with a one-line error
when no retarget answers or the choice is refused.
"""

from __future__ import annotations

import argparse
import json
import logging

import msgpack

from shared.bus import add_bus_args, open_session, query, query_when_ready
from shared.keys import Keys

log = logging.getLogger("mimic.source")


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("name", nargs="?", default=None, help="source to follow (a frame's `source`; omit: show)")
    g.add_argument("--auto", action="store_true", help="choose none: follow the first source seen")
    p.add_argument("--force", action="store_true", help="choose a source no frame has come from yet")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for retarget's answer")
    add_bus_args(p)


def main(args: argparse.Namespace) -> int:
    key = Keys(args.session).retarget_source
    with open_session(args) as z:
        try:
            before = msgpack.unpackb(query_when_ready(z, key, args.timeout))
            now = before
            if args.name is not None or args.auto:
                name = "" if args.auto else args.name
                if name and name not in before["sources"] and not args.force:
                    log.error(
                        "no frame from source %r has reached retarget on session %r (seen: %s): start it first "
                        "or pass --force",
                        name,
                        args.session,
                        ", ".join(sorted(before["sources"])) or "none",
                    )
                    return 1
                now = msgpack.unpackb(query(z, key, msgpack.packb({"source": name}), timeout=args.timeout))
        except RuntimeError as exc:
            log.error(
                "no retarget answered on session %r (%s): is the stack up on this endpoint/session?", args.session, exc
            )
            return 1
    print(
        json.dumps(
            {"follow": now["follow"], "chosen": now["chosen"], "was": before["follow"]} | {"sources": now["sources"]}
        )
    )
    return 0
