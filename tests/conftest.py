"""Shared fixtures: the real mocap data handed beside the repo, free ports, a router, the G1 models."""

from __future__ import annotations

from pathlib import Path

import pytest

from shared.bus import free_port
from shared.paths import REPO_ROOT
from shared.paths import mocap_dir as _mocap_dir

REPO = REPO_ROOT
#: Real recorded motion lives beside the repo (never copied into it).
MOCAP_DIR = _mocap_dir()


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile (or load) the solver's numba kernels once before any test: many tests start solver processes
    with a deadline, and with a stale cache (a kernel edited since ``make setup``) the first of them would
    otherwise spend ~10 s of CPU compiling them. Cached, this costs about 1 s."""
    from services.solver import hqp_kernel, tick_kernel

    hqp_kernel.warm_up()
    tick_kernel.warm_up()


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"real mocap data not found at {path} (set MIMIC_MOCAP_DIR); it is read at run time, never copied")
    return path


@pytest.fixture(scope="session")
def mocap_dir() -> Path:
    return _require(MOCAP_DIR)


@pytest.fixture(scope="session")
def bvh_clips() -> list[Path]:
    clips = sorted(_require(MOCAP_DIR / "bvh").glob("*.bvh"))
    if not clips:
        pytest.skip(f"no .bvh clips in {MOCAP_DIR / 'bvh'}")
    return clips


@pytest.fixture(scope="session")
def c3d_dir() -> Path:
    return _require(MOCAP_DIR / "c3d")


@pytest.fixture()
def zenoh_endpoint() -> str:
    """A fresh loopback endpoint for a router started by the test."""
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture()
def router(zenoh_endpoint):
    """A Zenoh router inside the test process (``mimic router``'s config) on a fresh loopback endpoint.

    Yields:
        the endpoint clients connect to, e.g. ``tcp/127.0.0.1:PORT``.
    """
    import zenoh

    from services.router.cli import router_config

    with zenoh.open(router_config([zenoh_endpoint], None)):
        yield zenoh_endpoint


@pytest.fixture()
def local_stack(zenoh_endpoint):
    """A :class:`LocalStack` on a fresh loopback router and session; stopped after the test.

    Nothing runs yet: call ``start_router()`` or ``start_all([...])`` (which waits on liveliness).
    """
    from services.launcher.local_stack import LocalStack

    session = f"t{zenoh_endpoint.rsplit(':', 1)[1]}"
    with LocalStack(session, zenoh_endpoint, status_period=0.2) as stack:
        yield stack


@pytest.fixture(scope="session")
def mocap_sources(mocap_dir):
    """SOURCES.md of the real mocap data, parsed (the facts tests check clips against)."""
    from tests.support.mocap_sources import MocapSources

    return MocapSources.read(mocap_dir)


@pytest.fixture(scope="session")
def robot17():
    """The default robot (G1) with its waist: 17 controlled joints."""
    from shared.robot.pinocchio_model import build_robot_model

    return build_robot_model()


@pytest.fixture(scope="session")
def robot14():
    """The G1 reduced to the 14 arm joints (waist at rest)."""
    from shared.robot.pinocchio_model import build_robot_model

    return build_robot_model(with_waist=False)
