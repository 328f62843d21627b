"""A running service (retarget) under adversarial payloads over a real router on loopback."""

from __future__ import annotations

import pytest

from tests.fuzz.live_fuzz import SERVICES, payload_mix, run_against

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_retarget_counts_every_bad_payload_and_emits_no_nan(local_stack):
    payloads = payload_mix("HumanFrame", 200, rng_seed=7)
    report = run_against(local_stack, SERVICES["retarget"], payloads, rate=500, timeout=40)
    assert report["service_alive"] and report["handler_errors"] == 0, report
    assert sum(report["expected_rejects"].values()) > 50  # the mix really was mostly bad
    if report["dropped"] + report["gaps"] == 0:  # nothing evicted unread or lost: every bad payload counted
        assert report["decoder_rejects_counted"] == report["expected_rejects"], report
    assert report["outputs_ok"] > 0 and report["outputs_bad"] == {}, report
    # Backwards time is a service-level reject, counted too (a lower seq with a later t0 is a restarted
    # source and accepted; a stamp going backwards within one source is not).
    rej = report["service_rejects"]
    assert rej.get("seq_backwards", 0) + rej.get("time_backwards", 0) > 0, report
    assert report["ok"], report
