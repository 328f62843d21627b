"""Run services as child processes: prefixed logs, clean stop, restart with backoff."""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import IO

log = logging.getLogger("mimic.up")
_PR_SET_PDEATHSIG = 1


def rss_mb(pid: int) -> float | None:
    """Resident set size of ``pid`` [MiB] from /proc (None when it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def stop_processes(
    *procs: subprocess.Popen | None, sig: int = signal.SIGINT, timeout: float = 10.0
) -> list[int | None]:
    """Stop processes in the given order: ``sig``, then SIGKILL after ``timeout`` [s].

    None entries and processes that already exited are skipped. Returns each exit code
    (None for skipped ones; a killed process reports its negative signal number).
    """
    codes: list[int | None] = []
    for proc in procs:
        if proc is None or proc.poll() is not None:
            codes.append(None if proc is None else proc.returncode)
            continue
        proc.send_signal(sig)
        try:
            codes.append(proc.wait(timeout))
        except subprocess.TimeoutExpired:
            proc.kill()
            codes.append(proc.wait())
    return codes


def _die_with_parent() -> None:  # pragma: no cover - runs in the child
    # If the launcher is SIGKILLed, the kernel still takes its children down: no orphans.
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


@dataclass
class Child:
    """One supervised service process."""

    name: str
    argv: list[str]
    env: dict[str, str]
    restart: bool = False
    proc: subprocess.Popen | None = None
    restarts: int = 0
    exit_codes: list[int] = field(default_factory=list)
    next_start: float = 0.0
    stopping: bool = False
    #: a long-running service (an exit nobody asked for is news) rather than a one-shot job
    service: bool = True


class Supervisor:
    """Start, watch and stop a set of local service processes.

    Args:
        out: stream the prefixed child logs go to.
        backoff: (initial, maximum) restart delay [s], doubled after each crash.
    """

    def __init__(self, out: IO[str] | None = None, backoff: tuple[float, float] = (0.5, 8.0), cwd: str | None = None):
        self.out = out or sys.stdout
        self.backoff = backoff
        self.cwd = cwd
        self.children: dict[str, Child] = {}
        self._lock = threading.Lock()
        self._width = 8

    def start(
        self, name: str, argv: list[str], env: dict[str, str], restart: bool = False, service: bool = True
    ) -> Child:
        """Start ``argv`` as child ``name``; ``service=False`` for a one-shot job whose exit 0 is its success."""
        child = Child(name, argv, env, restart, service=service)
        self.children[name] = child
        self._width = max(self._width, len(name))
        self._spawn(child)
        return child

    def _spawn(self, child: Child) -> None:
        env = dict(os.environ)
        env.update(child.env)
        env.setdefault("PYTHONUNBUFFERED", "1")
        child.proc = subprocess.Popen(
            child.argv,
            env=env,
            cwd=self.cwd,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            start_new_session=True,
            preexec_fn=_die_with_parent,
        )
        log.info("started %s (pid %d): %s", child.name, child.proc.pid, " ".join(child.argv))
        threading.Thread(target=self._pump, args=(child, child.proc), daemon=True).start()

    def _pump(self, child: Child, proc: subprocess.Popen) -> None:
        prefix = f"{child.name:<{self._width}} | "
        for line in proc.stdout:
            with self._lock:
                self.out.write(prefix + line)
                self.out.flush()

    def poll(self) -> list[str]:
        """Check children; restart crashed ones whose backoff elapsed. Returns names that exited."""
        exited = []
        now = time.monotonic()
        for child in self.children.values():
            if child.proc is None:
                if child.restart and not child.stopping and now >= child.next_start:
                    child.restarts += 1
                    log.warning("restarting %s (restart #%d)", child.name, child.restarts)
                    self._spawn(child)
                continue
            code = child.proc.poll()
            if code is None:
                continue
            child.exit_codes.append(code)
            child.proc = None
            exited.append(child.name)
            if child.stopping:
                continue
            if child.restart:
                delay = min(self.backoff[1], self.backoff[0] * 2 ** min(child.restarts, 10))
                child.next_start = now + delay
                log.warning("%s exited with %d; restart in %.1f s", child.name, code, delay)
            elif code == 0 and not child.service:
                log.info("%s finished", child.name)
            elif code == 0:
                # Not a crash: the process was stopped from outside (SIGTERM/SIGINT, e.g. replaced by
                # hand) and shut down cleanly. The stack goes on without it.
                log.warning(
                    "%s stopped (exit 0) without being asked by this stack: stopped from outside? the stack runs "
                    "on without it%s",
                    child.name,
                    ""
                    if child.name != "solver"
                    else " (the sim holds its last pose until a followed solver publishes again: mimic follow ID;"
                    " mimic swap-solver --algo ALGO replaces a solver without a gap)",
                )
            else:
                log.warning(
                    "%s exited with %d (crashed: see its last lines above; --restart restarts it)", child.name, code
                )
        return exited

    def alive(self, name: str) -> bool:
        c = self.children.get(name)
        return c is not None and c.proc is not None and c.proc.poll() is None

    def stop(self, name: str, timeout: float = 8.0) -> int | None:
        """SIGTERM, wait, then SIGKILL the child's whole process group."""
        child = self.children[name]
        child.stopping = True
        proc = child.proc
        if proc is None:
            return child.exit_codes[-1] if child.exit_codes else None
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            code = proc.wait(timeout)
        except subprocess.TimeoutExpired:
            log.warning("%s did not stop within %.0f s: SIGKILL", name, timeout)
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            code = proc.wait()
        child.exit_codes.append(code)
        child.proc = None
        return code

    def stop_all(self, order: list[str] | None = None) -> dict[str, int | None]:
        """Stop every child, in ``order`` (default: reverse start order)."""
        names = order or list(reversed(self.children))
        return {n: self.stop(n) for n in names}
