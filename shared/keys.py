"""Zenoh key expressions: the only place a key string is written.

Layout: ``mimic/<session>/<stage>/...``. ``session`` separates operators or
experiments sharing one bus; it must be a single key chunk.
"""

from __future__ import annotations

import re

ROOT = "mimic"
DEFAULT_SESSION = "default"
_CHUNK = re.compile(r"^[A-Za-z0-9_\-]+$")


def _chunk(value: str, what: str) -> str:
    if not _CHUNK.match(value):
        raise ValueError(f"{what} {value!r} must match [A-Za-z0-9_-]+ (one key chunk)")
    return value


class Keys:
    """All key expressions of one session."""

    def __init__(self, session: str = DEFAULT_SESSION):
        self.session = _chunk(session, "session")
        self.prefix = f"{ROOT}/{self.session}"

    # data streams
    @property
    def mocap_frame(self) -> str:
        return f"{self.prefix}/mocap/frame"

    @property
    def targets(self) -> str:
        return f"{self.prefix}/retarget/targets"

    def command(self, solver_id: str) -> str:
        return f"{self.prefix}/solver/{_chunk(solver_id, 'solver id')}/command"

    @property
    def all_commands(self) -> str:
        return f"{self.prefix}/solver/*/command"

    @property
    def sim_state(self) -> str:
        return f"{self.prefix}/sim/state"

    # health and control
    def status(self, service: str, instance: str | None = None) -> str:
        svc = _chunk(service, "service")
        return (
            f"{self.prefix}/{svc}/status"
            if instance is None
            else f"{self.prefix}/{svc}/{_chunk(instance, 'instance')}/status"
        )

    @property
    def all_status(self) -> str:
        return f"{self.prefix}/**/status"

    def alive(self, service: str, instance: str) -> str:
        return f"{self.prefix}/alive/{_chunk(service, 'service')}/{_chunk(instance, 'instance')}"

    @property
    def all_alive(self) -> str:
        return f"{self.prefix}/alive/**"

    def config(self, service: str) -> str:
        """Queryable returning (GET) or setting (payload) a service's config."""
        return f"{self.prefix}/{_chunk(service, 'service')}/config"

    @property
    def calibration(self) -> str:
        return f"{self.prefix}/retarget/calibration"

    @property
    def retarget_source(self) -> str:
        """Queryable: which mocap source retarget follows (a payload chooses one)."""
        return f"{self.prefix}/retarget/source"

    @property
    def sim_follow(self) -> str:
        """Queryable: which solver id the sim follows."""
        return f"{self.prefix}/sim/follow"

    @property
    def stack_solver(self) -> str:
        """Queryable of ``mimic up``: replace the solver the sim follows (``mimic swap-solver``)."""
        return f"{self.prefix}/stack/solver"

    @property
    def everything(self) -> str:
        return f"{self.prefix}/**"

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
