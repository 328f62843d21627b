"""The stack definition, read from ``docker-compose.yml``.

The compose file is the single description of the services: ``mimic up`` runs
exactly its commands and environment as local processes, so the containers
and the embedded default cannot drift apart. The only local rewrite is the
network: ``MIMIC_CONNECT`` and ``MIMIC_ROUTER_LISTEN`` point at loopback, and
``MIMIC_MODE`` is peer.

Why the mode differs: each container has a loopback of its own, so the loopback
listeners that let local peers reach each other directly are unreachable across
containers; there the services are clients and the router carries everything.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from shared.paths import REPO_ROOT

COMPOSE_FILE = REPO_ROOT / "docker-compose.yml"
ROUTER_SERVICE = "zenoh"
#: Environment variables that carry network endpoints: rewritten for loopback.
NETWORK_ENV = ("MIMIC_CONNECT", "MIMIC_ROUTER_LISTEN", "MIMIC_MODE")
#: Zenoh mode of a local stack's services.
LOCAL_MODE = "peer"
_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::?-([^}]*))?\}")


@dataclass
class ServiceSpec:
    """One service of the stack.

    Attributes:
        name: compose service name. command: argv list (``mimic ...``).
        environment: variables set for it. profiles: compose profiles (empty = always on).
    """

    name: str
    command: list[str]
    environment: dict[str, str] = field(default_factory=dict)
    profiles: list[str] = field(default_factory=list)


def interpolate(value: str, env: dict[str, str]) -> str:
    """Compose-style ``${VAR}`` / ``${VAR:-default}`` substitution."""

    def sub(m: re.Match) -> str:
        name, default = m.group(1), m.group(2)
        val = env.get(name)
        return val if val else (default or "")

    return _VAR.sub(sub, value)


def load_stack(path: Path = COMPOSE_FILE, env: dict[str, str] | None = None) -> dict[str, ServiceSpec]:
    """Services of the compose file with variables interpolated from ``env`` (default os.environ)."""
    env = dict(os.environ if env is None else env)
    doc = yaml.safe_load(path.read_text())
    out: dict[str, ServiceSpec] = {}
    for name, svc in (doc.get("services") or {}).items():
        cmd = svc.get("command")
        if isinstance(cmd, str):
            cmd = cmd.split()
        if not cmd:
            raise ValueError(f"{path}: service {name!r} has no command")
        raw_env = svc.get("environment") or {}
        if isinstance(raw_env, list):
            raw_env = dict(item.split("=", 1) for item in raw_env)
        out[name] = ServiceSpec(
            name=name,
            command=[interpolate(str(c), env) for c in cmd],
            environment={k: interpolate(str(v), env) for k, v in raw_env.items()},
            profiles=list(svc.get("profiles") or []),
        )
    return out


def select(
    stack: dict[str, ServiceSpec], profiles: list[str] | None = None, only: list[str] | None = None
) -> list[ServiceSpec]:
    """Services to run: those without a profile plus the named profiles' (router first)."""
    profiles = set(profiles or [])
    known = sorted({p for s in stack.values() for p in s.profiles})
    if profiles - set(known):
        raise ValueError(f"unknown profile(s) {sorted(profiles - set(known))}; known: {', '.join(known)}")
    chosen = [s for s in stack.values() if not s.profiles or profiles & set(s.profiles)]
    if only:
        unknown = set(only) - set(stack)
        if unknown:
            raise ValueError(f"unknown services {sorted(unknown)}; known: {sorted(stack)}")
        chosen = [s for s in stack.values() if s.name in only or s.name == ROUTER_SERVICE]
    chosen.sort(key=lambda s: s.name != ROUTER_SERVICE)
    return chosen


#: Host part of a "bind every interface" address in a compose command (containers need it).
ALL_INTERFACES = "0.0.0.0:"


def local_command(command: list[str]) -> list[str]:
    """The compose command as run locally: addresses binding every interface moved to loopback.

    In a container ``0.0.0.0`` is reachable only through the ports compose publishes (on
    127.0.0.1); run on the host it would expose an unauthenticated port (the UDP ingest) to the
    network, against the threat model. A user who wants that starts the service by hand.
    """
    return ["127.0.0.1:" + c[len(ALL_INTERFACES) :] if c.startswith(ALL_INTERFACES) else c for c in command]


def local_environment(spec: ServiceSpec, endpoint: str, session: str | None = None) -> dict[str, str]:
    """The service's compose environment with network endpoints moved to loopback."""
    env = dict(spec.environment)
    if "MIMIC_CONNECT" in env:
        env["MIMIC_CONNECT"] = endpoint
    if "MIMIC_ROUTER_LISTEN" in env:
        env["MIMIC_ROUTER_LISTEN"] = endpoint
    if "MIMIC_MODE" in env:
        env["MIMIC_MODE"] = LOCAL_MODE
    if session is not None and "MIMIC_SESSION" in env:
        env["MIMIC_SESSION"] = session
    return env


#: Flags naming a file a service keeps across its own restarts (not across stacks).
STATE_FLAGS = ("--calibration-state",)


def forget_state(specs: Iterable[ServiceSpec], root: Path, session: str | None = None) -> list[Path]:
    """Delete the state files (``STATE_FLAGS``) of the given services; returns those removed.

    A new stack is a new operator session: the retarget calibration must come from that
    operator's rest pose, not from the last run. Supervisor restarts keep the file, so a
    crashed retarget comes back with the calibration it had. Relative paths are from ``root``.
    """
    removed = []
    if session is not None:  # files services derive from the session themselves (the sim's last state)
        from services.sim.resume import session_state_file

        path = root / session_state_file(session)
        if path.exists():
            path.unlink()
            removed.append(path)
    for spec in specs:
        for flag, value in zip(spec.command, spec.command[1:]):
            if flag in STATE_FLAGS and (root / value).exists():
                (root / value).unlink()
                removed.append(root / value)
    return removed
