"""``mimic swap-solver --algo ALGO [--id ID]``: replace the running solver of a local stack in one step.

Asks the ``mimic up`` of the session (``keys.stack_solver``, :mod:`services.launcher.solver_swap`)
to start a solver with another algorithm as one of its children, point the sim at it and stop
the one it followed. Without ``--algo`` it prints what the sim follows and which solvers the
stack runs. Prints the stack's answer as JSON; exit status 1 with a one-line error when the
stack refuses or no ``mimic up`` answers (a stack started otherwise: ``mimic solve`` then
``mimic follow``).
"""

from __future__ import annotations

import argparse
import json
import logging

import msgpack

from shared.bus import add_bus_args, open_session, query, query_when_ready
from shared.keys import Keys

log = logging.getLogger("mimic.swap")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--algo", default=None, help="algorithm of the new solver (omit: show the stack's solvers)")
    p.add_argument("--id", default=None, help="id of the new solver (default: the algorithm's name)")
    p.add_argument("--timeout", type=float, default=90.0, help="seconds to wait for the new solver to take over")
    add_bus_args(p)


def main(args: argparse.Namespace) -> int:
    key = Keys(args.session).stack_solver
    with open_session(args) as z:
        try:
            reply = query_when_ready(z, key, 3.0)  # GET: finds the route, and says what runs now
        except RuntimeError as exc:
            log.error(
                "no mimic up answered on session %r (%s): swap-solver replaces solvers of a stack started with "
                "mimic up; elsewhere start one with mimic solve --id ID and switch with mimic follow ID",
                args.session,
                exc,
            )
            return 1
        if args.algo is not None:
            request = {"algo": args.algo} | ({"id": args.id} if args.id else {})
            try:
                reply = query(z, key, msgpack.packb(request), timeout=args.timeout)
            except RuntimeError as exc:
                log.error("%s", str(exc).removeprefix(f"query {key} failed: "))
                return 1
    print(json.dumps(msgpack.unpackb(reply)))
    return 0
