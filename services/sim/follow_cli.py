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


def alive_solvers(z, keys: Keys, wait: float = 0.5, want: str | None = None, attempt: float = 0.5) -> list[str]:
    """Solver ids holding a liveliness token on the session, pooled over short gets.

    Each get is bounded by ``attempt`` [s]; the ids of all of them are pooled until ``want`` is
    among them, or (no ``want``) some get ended before its timeout with tokens in the pool (every
    route answered), or ``wait`` [s] has passed. An empty or partial answer is common from a fresh
    session on a loaded machine (its query not routed yet, a peer slow to answer: "alive: none"
    beside two live solvers), and one long get could spend the whole wait on such a query.
    """
    deadline = time.monotonic() + wait
    pool: set[str] = set()
    while True:
        timeout = max(0.05, min(attempt, deadline - time.monotonic()))
        t0 = time.monotonic()
        for r in z.liveliness().get(keys.all_alive, timeout=timeout):
            parsed = Keys.parse_alive(str(r.ok.key_expr)) if r.ok is not None else None
            if parsed and parsed[0] == "solver":
                pool.add(parsed[1])
        complete = time.monotonic() - t0 < 0.9 * timeout
        done = want in pool if want is not None else bool(pool) and complete
        if done or time.monotonic() >= deadline:
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
