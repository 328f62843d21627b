"""A running service (retarget) under adversarial payloads over a real router on loopback."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from services.launcher.supervisor import stop_processes
from shared.paths import REPO_ROOT
from tests.fuzz.live_fuzz import SERVICES, fuzz_live_service, payload_mix

REPO = REPO_ROOT
pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_retarget_counts_every_bad_payload_and_emits_no_nan(zenoh_endpoint):
    cli = [sys.executable, "-m", "services.cli"]
    target = SERVICES["retarget"]
    payloads = payload_mix("HumanFrame", 200, rng_seed=7)
    router = subprocess.Popen([*cli, "router", "--listen", zenoh_endpoint], cwd=REPO, stdout=subprocess.DEVNULL)
    procs = [router]
    try:
        time.sleep(0.8)
        svc = subprocess.Popen(
            [*cli, *target.argv, "--connect", zenoh_endpoint, "--session", "fuzzlive", "--status-period", "0.2"],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        procs.append(svc)
        report = fuzz_live_service(zenoh_endpoint, "fuzzlive", target, payloads, svc, rate=500, timeout=40)
    finally:
        stop_processes(*reversed(procs))
    assert report["service_alive"] and report["handler_errors"] == 0, report
    assert sum(report["expected_rejects"].values()) > 50  # the mix really was mostly bad
    if report["dropped"] == 0:  # nothing evicted unread: every bad payload counted under its own reason
        assert report["decoder_rejects_counted"] == report["expected_rejects"], report
    assert report["outputs_ok"] > 0 and report["outputs_bad"] == {}, report
    # Backwards time is a service-level reject, counted too.
    assert report["service_rejects"].get("seq_backwards", 0) > 0, report
    assert report["ok"]
