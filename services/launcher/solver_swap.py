"""Replace the running solver of a local stack: the one step behind ``mimic swap-solver``.

``mimic up`` serves ``keys.stack_solver``; a request (msgpack ``{"algo": ALGO, "id": ID?}``)
makes the stack, in its own main loop:

1. start a solver with the new algorithm and id as one of its supervised children (the
   command line of the solver it replaces, with ``--algo`` and ``--id`` changed);
2. wait for its liveliness token (it starts from the robot's measured state);
3. point the sim at it (``keys.sim_follow``), so there is no moment without a followed solver;
4. stop the solver the sim followed before, if this stack started it (then it is "stopped by
   the stack", not a crash or an unexplained exit).

The reply says what happened (``{"follow", "was", "algo", "stopped"}``); a failure (an
unknown algorithm, a solver that does not come up) is an error reply in one line, and the old
solver keeps running and followed.
"""

from __future__ import annotations

import logging

import msgpack
import zenoh

from services.launcher.local_stack import LocalStack
from shared.bus import query
from shared.messages import MessageError, parse_query

log = logging.getLogger("mimic.up")
#: The id a solver has when its command line names none (SolverConfig.solver_id's default).
DEFAULT_SOLVER_ID = "main"


def _flag(argv: list[str], flag: str) -> str | None:
    return argv[argv.index(flag) + 1] if flag in argv[:-1] else None


def is_solver(argv: list[str]) -> bool:
    """Whether ``argv`` (as the stack runs it: ``python -m services.cli solve ...``) runs a solver."""
    return "solve" in argv[:4]


def solver_id(argv: list[str]) -> str:
    """The solver id a solver command line publishes under."""
    return _flag(argv, "--id") or DEFAULT_SOLVER_ID


def with_flags(argv: list[str], **flags: str) -> list[str]:
    """``argv`` with each ``--<flag> VALUE`` replaced (or appended); ``solver_id`` is ``--id``."""
    out = list(argv)
    for name, value in flags.items():
        flag = "--id" if name == "solver_id" else "--" + name.replace("_", "-")
        if flag in out[:-1]:
            out[out.index(flag) + 1] = value
        else:
            out += [flag, value]
    return out


class SolverSwap:
    """Serves ``keys.stack_solver`` for a :class:`LocalStack`; call :meth:`poll` from the stack's loop.

    The queryable is a FIFO, answered from :meth:`poll`: starting and stopping children is the
    main loop's business (the supervisor is not thread-safe), and waiting for the new solver
    must not block a Zenoh callback thread (liveliness arrives on one).
    """

    def __init__(self, stack: LocalStack, timeout: float = 60.0):
        self.stack = stack
        self.timeout = timeout
        self._q = stack.bus.declare_queryable(stack.keys.stack_solver)

    def poll(self) -> None:
        """Answer every pending request (each may take seconds: a solver starting)."""
        while (q := self._q.try_recv()) is not None:
            self._answer(q)

    def _answer(self, q: zenoh.Query) -> None:
        try:
            payload = q.payload.to_bytes() if q.payload is not None else b""
            req = parse_query(payload) if payload else {}
            if not isinstance(req, dict):
                raise ValueError(f"expected a map {{algo, id}}, got {type(req).__name__}")
            reply = self.current() if not req else self.replace(str(req.get("algo", "")), req.get("id"))
            q.reply(self.stack.keys.stack_solver, msgpack.packb(reply))
        except (ValueError, RuntimeError, MessageError) as exc:
            msg = str(exc).splitlines()[0]
            log.error("solver swap refused: %s", msg)
            q.reply_err(msg.encode())
        finally:
            q.drop()

    def _followed(self) -> str:
        return msgpack.unpackb(query(self.stack.bus, self.stack.keys.sim_follow, timeout=3.0))["follow"]

    def _child_of(self, sid: str) -> str | None:
        """The stack's running child that is solver ``sid``."""
        for name, argv in self.stack.argv.items():
            if is_solver(argv) and solver_id(argv) == sid and self.stack.running(name):
                return name
        return None

    def current(self) -> dict:
        """What the sim follows and which solvers this stack runs."""
        return {
            "follow": self._followed(),
            "solvers": {
                solver_id(a): _flag(a, "--algo")
                for n, a in self.stack.argv.items()
                if is_solver(a) and self.stack.running(n)
            },
        }

    def replace(self, algo: str, new_id: str | None = None) -> dict:
        """Start solver ``algo`` (id ``new_id``, default the algorithm's name), follow it, stop the old one."""
        from services.solver.registry import ALGORITHMS

        if algo not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {algo!r}; known: {', '.join(sorted(ALGORITHMS))}")
        was = self._followed()
        old = self._child_of(was)
        new_id = new_id or algo
        if new_id == was or self._child_of(new_id) is not None:
            raise ValueError(f"a solver {new_id!r} already runs: choose another id")
        base = self.stack.argv[old] if old else self.stack.command("solver")[0]
        env = self.stack.env[old] if old else self.stack.command("solver")[1]
        name = f"solver/{new_id}"
        self.stack.start(name, argv=with_flags(base, algo=algo, solver_id=new_id), env=env, restart=self.stack.restart)
        try:
            self.stack.wait_alive([f"solver/{new_id}"], self.timeout)
            query(self.stack.bus, self.stack.keys.sim_follow, new_id.encode(), timeout=3.0)
        except RuntimeError as exc:
            self.stack.sup.stop(name)
            raise RuntimeError(
                f"solver {new_id!r} ({algo}) did not take over, {was!r} is still followed: {exc}"
            ) from None
        if old is not None:
            self.stack.sup.stop(old)
        log.info(
            "solver %r replaced by %r (%s): the sim follows %r%s",
            was,
            new_id,
            algo,
            new_id,
            f", {old} stopped" if old else f"; {was!r} was not started by this stack and keeps running",
        )
        return {"follow": new_id, "was": was, "algo": algo, "stopped": old is not None}

    def close(self) -> None:
        self._q.undeclare()
