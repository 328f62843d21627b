"""The one way to start a local stack: router and services as child processes.

``mimic up``, the benches (``mimic bench pipeline|recorder``, the soak) and the
tests start services through :class:`LocalStack`. The commands and environment
come from docker-compose.yml (:mod:`services.launcher.stack`); any other command
line (``mimic record``, a second solver) can be started beside them.

Readiness is the services' own word: every :class:`~shared.bus.ServiceRunner`
declares the liveliness token ``mimic/<session>/alive/<service>/<instance>``,
and :meth:`LocalStack.wait_alive` blocks until the named tokens are present.
The only port wait is for the router itself (before it listens there is no bus
to watch liveliness on).

Example::

    with LocalStack("s1", f"tcp/127.0.0.1:{free_port()}") as stack:
        stack.start_all(["retarget", "solver", "sim"])   # returns once all three are alive
        ...
"""

from __future__ import annotations

import io
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import IO

import zenoh

from services.launcher.session_lock import SessionLock
from services.launcher.stack import (
    COMPOSE_FILE,
    REPO_ROOT,
    ROUTER_SERVICE,
    forget_state,
    load_stack,
    local_command,
    local_environment,
)
from services.launcher.supervisor import Supervisor
from shared.bus import bus_args, open_session, wait_for_endpoint
from shared.keys import Keys

log = logging.getLogger("mimic.stack")
#: How long the router may take to open its port [s].
ROUTER_TIMEOUT_S = 20.0
#: Compose service names whose processes announce another ServiceRunner name.
ALIVE_ALIAS = {"solver-shadow": "solver/shadow"}


def mimic_argv(command: list[str]) -> list[str]:
    """``mimic ARGS`` as ``<this python> -m services.cli ARGS``, so it works from any venv."""
    if command and command[0] == "mimic":
        return [sys.executable, "-m", "services.cli", *command[1:]]
    return list(command)


def alive_name(service: str) -> str:
    """The liveliness name (``service`` or ``service/instance``) a compose service announces."""
    return ALIVE_ALIAS.get(service, service)


class LocalStack:
    """Router and services of one session on loopback, each startable, killable and restartable alone.

    Args:
        session: bus session name (``mimic/<session>/...``).
        endpoint: router endpoint, e.g. ``tcp/127.0.0.1:7450``.
        env: variables for the compose interpolation (e.g. ``{"SOLVER": "wqp"}``).
        status_period: ServiceStatus period given to every compose service [s] (None: theirs).
        out: where the prefixed child output goes (default: kept in memory, see :meth:`output`).
        restart: restart crashed services with exponential backoff.
        compose: compose file (default the repo's docker-compose.yml).
        cwd: working directory of the children (relative state paths are from here).
    """

    def __init__(
        self,
        session: str,
        endpoint: str,
        env: dict[str, str] | None = None,
        status_period: float | None = None,
        out: IO[str] | None = None,
        restart: bool = False,
        compose: Path | None = None,
        cwd: Path = REPO_ROOT,
    ):
        self.session = session
        self.endpoint = endpoint
        self.status_period = status_period
        self.restart = restart
        self.cwd = Path(cwd)
        self.keys = Keys(session)
        self.spec = load_stack(compose or COMPOSE_FILE, {**os.environ, "MIMIC_SESSION": session, **(env or {})})
        self._log = io.StringIO() if out is None else None
        self.sup = Supervisor(out=out or self._log, cwd=str(self.cwd))
        self.argv: dict[str, list[str]] = {}
        self.env: dict[str, dict[str, str]] = {}
        self._z: zenoh.Session | None = None
        self._alive_sub = None
        self._lock = threading.Lock()
        self.alive: set[tuple[str, str]] = set()  # (service, instance) holding a token now
        # Before any file is touched: a live stack of this session keeps its files (SessionBusyError).
        self.session_lock = SessionLock(self.cwd / "runs", session)
        self.session_lock.acquire()
        # A new stack is a new operator session: no state from an earlier run.
        for path in forget_state(self.spec.values(), self.cwd, session):
            log.info("new stack: removed the previous service state %s", path)

    # ------------------------------------------------------------------ commands

    def command(self, name: str, extra: list[str] | None = None) -> tuple[list[str], dict[str, str]]:
        """argv and environment of compose service ``name`` on this router and session."""
        spec = self.spec[name]
        argv = [*mimic_argv(local_command(spec.command)), *(extra or [])]
        if name != ROUTER_SERVICE and self.status_period is not None:
            argv += ["--status-period", str(self.status_period)]
        return argv, local_environment(spec, self.endpoint, self.session)

    def client_env(self) -> dict[str, str]:
        """Environment for a non-compose ``mimic`` command joining this stack."""
        return {"MIMIC_SESSION": self.session, "MIMIC_CONNECT": self.endpoint}

    def start(
        self,
        name: str,
        extra: list[str] | None = None,
        argv: list[str] | None = None,
        env: dict | None = None,
        service: bool = True,
        restart: bool | None = None,
    ) -> float:
        """Start a service; again with no arguments: the same command. Returns the monotonic start time [s].

        ``name`` is a compose service unless ``argv`` (a full command line; ``mimic ...`` allowed)
        is given; such commands get :meth:`client_env` unless ``env`` is given. ``service=False``:
        a one-shot job (a clip player), whose exit 0 is logged as its success, not as news.
        ``restart``: restart it when it crashes (default: compose services, if the stack restarts).
        """
        if argv is None:
            if name in self.argv and extra is None:
                argv, env = self.argv[name], self.env[name]
            else:
                argv, env = self.command(name, extra)
        argv = mimic_argv(argv)
        env = env if env is not None else self.client_env()
        self.argv[name], self.env[name] = argv, env
        t = time.monotonic()
        restart = self.restart and name in self.spec if restart is None else restart
        self.sup.start(name, argv, env, restart=restart, service=service)
        return t

    def start_router(self, timeout: float = ROUTER_TIMEOUT_S) -> None:
        """Start the router, wait until it accepts connections, then watch liveliness through it.

        Raises:
            RuntimeError: something already listens on the endpoint (another stack's router: its
                port check and liveliness would pass for ours, and our services would join it).
        """
        if wait_for_endpoint(self.endpoint, 0.0):
            raise RuntimeError(
                f"router endpoint {self.endpoint} is busy (another mimic up?): stop it, or pass a free "
                "--endpoint tcp/127.0.0.1:PORT and another --session (mimic up --beside picks both)"
            )
        self.start(ROUTER_SERVICE)
        if not wait_for_endpoint(self.endpoint, timeout):
            raise RuntimeError(f"router not listening on {self.endpoint} after {timeout:.0f} s\n{self.output()}")
        self._z = open_session(bus_args(connect=[self.endpoint], session=self.session))
        self._alive_sub = self._z.liveliness().declare_subscriber(self.keys.all_alive, self._on_alive, history=True)

    def start_all(
        self,
        names: Iterable[str],
        extra: dict[str, list[str]] | None = None,
        timeout: float = 120.0,
        stop: threading.Event | None = None,
    ) -> None:
        """Router first, then the named compose services; returns once every one is alive."""
        names = [n for n in names if n != ROUTER_SERVICE]
        if ROUTER_SERVICE not in self.sup.children:
            self.start_router()
        for n in names:
            self.start(n, (extra or {}).get(n))
        self.wait_alive([alive_name(n) for n in names], timeout, stop)

    @property
    def bus(self) -> zenoh.Session:
        """The stack's own session on the router (open after :meth:`start_router`), for observers."""
        if self._z is None:
            raise RuntimeError("start the router first")
        return self._z

    # ------------------------------------------------------------------ readiness

    def _on_alive(self, sample: zenoh.Sample) -> None:
        parsed = Keys.parse_alive(str(sample.key_expr))
        if parsed is None:
            return
        with self._lock:
            (self.alive.discard if sample.kind == zenoh.SampleKind.DELETE else self.alive.add)(parsed)

    def missing(self, names: Iterable[str]) -> list[str]:
        """Those of ``names`` (``service`` = any instance, or ``service/instance``) without a token."""
        with self._lock:
            full = {f"{s}/{i}" for s, i in self.alive}
            services = {s for s, _ in self.alive}
        return sorted(n for n in names if n not in (full if "/" in n else services))

    def wait_alive(self, names: Iterable[str], timeout: float = 120.0, stop: threading.Event | None = None) -> None:
        """Block until each of ``names`` holds a liveliness token.

        Raises:
            RuntimeError: a service exited meanwhile (without ``restart``), ``stop`` was set,
                or ``timeout`` [s] passed; the message names the missing ones.
        """
        if self._z is None:
            raise RuntimeError("start the router first")
        names = list(names)
        deadline = time.monotonic() + timeout
        while missing := self.missing(names):
            exited = self.sup.poll()
            if exited and not self.restart:
                raise RuntimeError(f"services exited during start-up: {exited}\n{self.output()}")
            if (stop is not None and stop.is_set()) or time.monotonic() > deadline:
                raise RuntimeError(f"services not up after {timeout:.0f} s: {missing}\n{self.output()}")
            time.sleep(0.05)

    # ------------------------------------------------------------------ processes

    def pid(self, name: str) -> int | None:
        c = self.sup.children.get(name)
        return c.proc.pid if c is not None and c.proc is not None else None

    def pids(self) -> dict[str, int]:
        return {n: p for n in self.sup.children if (p := self.pid(n)) is not None}

    def kill9(self, name: str) -> int:
        """SIGKILL the service (no clean-up runs in it). Returns its pid."""
        child = self.sup.children[name]
        pid = child.proc.pid
        os.kill(pid, signal.SIGKILL)
        child.proc.wait(5)
        child.proc = None
        return pid

    def running(self, name: str) -> bool:
        return self.sup.alive(name)

    def output(self, tail: int | None = 6000) -> str:
        """The last ``tail`` characters (None: all) of the children's output (empty when it went to ``out``)."""
        text = self._log.getvalue() if self._log is not None else ""
        return text if tail is None else text[-tail:]

    def stop(
        self, last: Iterable[str] = ("logger",), timeout: float = 8.0, timeouts: dict[str, float] | None = None
    ) -> dict[str, int | None]:
        """Stop every child (reverse start order, ``last`` and the router at the end); exit codes by name.

        ``timeouts``: per-child grace before SIGKILL [s] (e.g. the logger compacting its recording).

        The stack's session (:attr:`bus`) stays open, so observers keep what the services said
        while stopping (their last status); :meth:`close` closes it.
        """
        tail = [*last, ROUTER_SERVICE]
        order = [n for n in reversed(self.sup.children) if n not in tail]
        order += [n for n in tail if n in self.sup.children]
        codes = {n: self.sup.stop(n, (timeouts or {}).get(n, timeout)) for n in order}
        if self.session_lock.held:
            forget_state(self.spec.values(), self.cwd, self.session)  # the stack's state lives as long as the stack
            self.session_lock.release()
        return codes

    def close(self, last: Iterable[str] = ("logger",), timeout: float = 8.0) -> dict[str, int | None]:
        """:meth:`stop`, then close the stack's own session; exit codes by name."""
        codes = self.stop(last, timeout)
        if self._alive_sub is not None:
            self._alive_sub.undeclare()
            self._alive_sub = None
        if self._z is not None:
            self._z.close()
            self._z = None
        return codes

    def __enter__(self) -> LocalStack:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
