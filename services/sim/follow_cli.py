"""``mimic follow [ID]``: which solver the running sim follows, or switch it (the local solver swap).

Talks to the sim's follow queryable (``keys.sim_follow``). Switching to an id no solver
announces on the bus (liveliness ``alive/solver/<ID>``) is refused in one line, unless
``--force`` (e.g. a solver about to start): the robot would otherwise hold its pose with
nobody commanding it. Exit status 1 with a one-line error when no sim answers.
"""

from __future__ import annotations

import argparse
import json
import logging
import time

import msgpack

from shared.bus import add_bus_args, control_session, query
from shared.keys import Keys

log = logging.getLogger("mimic.follow")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("id", nargs="?", default=None, help="solver id to follow (omit: print the one followed)")
    p.add_argument("--force", action="store_true", help="switch even when no solver with that id is alive")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for the sim's answer")
    add_bus_args(p)


def alive_solvers(
    z, keys: Keys, wait: float = 0.5, want: str | None = None, attempt: float = 0.5, settle: float = 0.5
) -> list[str]:
    """Solver ids holding a liveliness token on the session, pooled over short gets.

    A fresh session learns the other peers' tokens one peer at a time, so an early answer can be
    empty or partial even when every get completes (seen on a loaded machine: "alive: none", or
    one of two live solvers). Gets of at most ``attempt`` [s] are repeated and their ids pooled
    until the pool is non-empty, holds ``want`` (if given) and has not grown for ``settle`` [s],
    or until ``wait`` [s] has passed.
    """
    start = time.monotonic()
    deadline, grew = start + wait, start
    pool: set[str] = set()
    while True:
        timeout = max(0.05, min(attempt, deadline - time.monotonic()))
        before = len(pool)
        for r in z.liveliness().get(keys.all_alive, timeout=timeout):
            parsed = Keys.parse_alive(str(r.ok.key_expr)) if r.ok is not None else None
            if parsed and parsed[0] == "solver":
                pool.add(parsed[1])
        now = time.monotonic()
        if len(pool) > before:
            grew = now
        settled = bool(pool) and now - grew >= settle and (want is None or want in pool)
        if settled or now >= deadline:
            return sorted(pool)
        time.sleep(0.05)


def main(args: argparse.Namespace) -> int:
    keys = Keys(args.session)
    try:
        with control_session(args, keys.sim_follow, args.timeout, "no sim") as (z, state):
            before = msgpack.unpackb(state)["follow"]
            solvers = alive_solvers(z, keys, wait=args.timeout, want=args.id)
            if args.id is not None and args.id != before:
                if args.id not in solvers and not args.force:
                    log.error(
                        "no solver %r is alive on session %r (alive: %s): start it first "
                        "(mimic solve --id %s --algo ...) or pass --force",
                        args.id,
                        args.session,
                        ", ".join(solvers) or "none",
                        args.id,
                    )
                    return 1
                query(z, keys.sim_follow, args.id.encode(), timeout=args.timeout)
    except RuntimeError as exc:  # StackAbsentError, or the sim refused
        log.error("%s: is the stack up on this endpoint/session?", exc)
        return 1
    now = args.id or before
    print(json.dumps({"follow": now, "was": before, "solvers_alive": solvers}))
    return 0
