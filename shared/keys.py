"""Zenoh key expressions: the only place a key string is written.

Layout: ``mimic/<session>/<stage>/...``. ``session`` separates operators or
experiments sharing one bus; it must be a single key chunk.
"""

from __future__ import annotations

import re
from typing import overload

ROOT = "mimic"
DEFAULT_SESSION = "default"
_CHUNK = re.compile(r"^[A-Za-z0-9_\-]+$")


def _chunk(value: str, what: str) -> str:
    if not _CHUNK.match(value):
        raise ValueError(f"{what} {value!r} must match [A-Za-z0-9_-]+ (one key chunk)")
    return value


class _SessionKey:
    """A fixed key of a session, read as an attribute: ``keys.targets`` -> ``mimic/<session>/retarget/targets``."""

    def __init__(self, suffix: str, doc: str = ""):
        self.suffix = suffix
        self.__doc__ = doc or f"``mimic/<session>/{suffix}``"

    @overload
    def __get__(self, keys: None, owner: type) -> _SessionKey: ...
    @overload
    def __get__(self, keys: Keys, owner: type) -> str: ...
    def __get__(self, keys: Keys | None, owner: type) -> str | _SessionKey:
        return self if keys is None else f"{keys.prefix}/{self.suffix}"


class Keys:
    """All key expressions of one session."""

    # data streams
    mocap_frame = _SessionKey("mocap/frame")
    targets = _SessionKey("retarget/targets")
    all_commands = _SessionKey("solver/*/command")
    sim_state = _SessionKey("sim/state")
    # health and control
    all_status = _SessionKey("**/status")
    all_alive = _SessionKey("alive/**")
    calibration = _SessionKey("retarget/calibration")
    retarget_source = _SessionKey(
        "retarget/source", "Queryable: which mocap source retarget follows (a payload chooses one)."
    )
    sim_follow = _SessionKey("sim/follow", "Queryable: which solver id the sim follows.")
    stack_solver = _SessionKey(
        "stack/solver", "Queryable of ``mimic up``: replace the solver the sim follows (``mimic swap-solver``)."
    )
    everything = _SessionKey("**")

    def __init__(self, session: str = DEFAULT_SESSION):
        self.session = _chunk(session, "session")
        self.prefix = f"{ROOT}/{self.session}"

    def command(self, solver_id: str) -> str:
        return f"{self.prefix}/solver/{_chunk(solver_id, 'solver id')}/command"

    def status(self, service: str, instance: str | None = None) -> str:
        svc = _chunk(service, "service")
        return (
            f"{self.prefix}/{svc}/status"
            if instance is None
            else f"{self.prefix}/{svc}/{_chunk(instance, 'instance')}/status"
        )

    def alive(self, service: str, instance: str) -> str:
        return f"{self.prefix}/alive/{_chunk(service, 'service')}/{_chunk(instance, 'instance')}"

    def config(self, service: str) -> str:
        """Queryable returning (GET) or setting (payload) a service's config."""
        return f"{self.prefix}/{_chunk(service, 'service')}/config"

    @staticmethod
    def all_sessions() -> str:
        return f"{ROOT}/**"

    @staticmethod
    def parse_alive(key: str) -> tuple[str, str] | None:
        """(service, instance) from an alive key, or None."""
        parts = key.split("/")
        if len(parts) == 5 and parts[0] == ROOT and parts[2] == "alive":
            return parts[3], parts[4]
        return None

    @staticmethod
    def with_session(key: str, session: str) -> str:
        """``key`` moved from its own session to ``session`` (``mimic/<s>/x`` -> ``mimic/<session>/x``).

        Raises:
            ValueError: ``key`` is not a mimic session key, or ``session`` is not one key chunk.
        """
        old = Keys.session_of(key)
        if old is None:
            raise ValueError(f"{key!r} is not a {ROOT}/<session>/... key")
        return Keys(session).prefix + key[len(Keys(old).prefix) :]

    @staticmethod
    def in_any_session(expr: str) -> str:
        """A key expression relative to a session (``mocap/frame``) made absolute over every session."""
        return expr if expr.startswith(f"{ROOT}/") else f"{ROOT}/*/{expr}"

    @staticmethod
    def session_of(key: str) -> str | None:
        parts = key.split("/")
        return parts[1] if len(parts) > 1 and parts[0] == ROOT else None
