"""The pipeline bench's drop accounting: per service, per stream, mailbox and Zenoh-lost apart."""

from __future__ import annotations

from services.evaluation.pipeline_bench import path_drops, service_drops
from shared.messages import ServiceStatus


def _status(service: str, instance: str, counts: dict[str, int]) -> ServiceStatus:
    return ServiceStatus(service, instance, "ok", 1.0, counts=counts)


def test_drops_split_per_stream_and_kind_and_the_path_total_skips_feedback():
    statuses = {
        "a": _status("retarget", "main", {"received": 90, "dropped": 3, "dropped.frames": 3, "gaps.frames": 2}),
        "b": _status(
            "solver",
            "main",
            {"dropped.targets": 4, "dropped.sim_state": 50, "gaps.targets": 1, "gaps.sim_state": 7},
        ),
        "c": _status("solver", "shadow", {"gaps.targets": 5}),
    }
    drops = service_drops(statuses)
    assert drops["retarget"] == {"dropped": {"frames": 3}, "gaps": {"frames": 2}}
    assert drops["solver"] == {"dropped": {"targets": 4, "sim_state": 50}, "gaps": {"targets": 1, "sim_state": 7}}
    assert drops["solver/shadow"] == {"dropped": {}, "gaps": {"targets": 5}}
    assert path_drops(drops) == 3 + 2 + 4 + 1 + 5  # not the 57 on the sim_state feedback
