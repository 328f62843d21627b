"""``mimic bench pipeline --noop``: the no-work stand-ins as real processes on a real router (loopback)."""

from __future__ import annotations

import argparse

import pytest

from services.evaluation import pipeline_bench
from services.evaluation.relay import DELIVERIES, command_message, state_message, targets_message
from shared.messages import Header, JointCommand, RobotState, TaskTargets
from shared.robot.profile import load_profile
from shared.targets import TARGET_NAMES


def test_the_stand_ins_outputs_are_valid_messages_shaped_like_the_services():
    joints = list(load_profile().controlled_joints(True))
    hdr = Header(7, 0.035, 123)
    for cls, msg in (
        (TaskTargets, targets_message()),
        (JointCommand, command_message(joints)),
        (RobotState, state_message(joints)),
    ):
        msg.hdr = hdr
        back = cls.decode(msg.encode())  # the full schema check the next stage runs
        assert back.hdr == hdr
    assert set(targets_message().targets) == set(TARGET_NAMES)
    assert len(command_message(joints).q) == len(joints) == 17


def _args(delivery: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    pipeline_bench.add_arguments(p)
    return p.parse_args(["--noop", "--delivery", delivery, "--rate", "100", "--duration", "1.5", "--warmup", "0.5"])


@pytest.mark.parametrize("delivery", DELIVERIES)
def test_noop_pipeline_moves_frames_through_three_processes_and_reports_them(delivery):
    res = pipeline_bench.run(_args(delivery))
    assert res["noop"] is True and res["delivery"] == delivery and res["algo"] is None
    sent = res["sent"]
    assert sent == 150
    # 100 Hz through three no-op processes: most frames reach the end even when the tests run niced on a
    # saturated machine (the real services, started in their place, got 51 of 150 through in that case).
    assert res["received"] >= 0.5 * sent, res["dropped"]
    lat = res["hop_latency_ms"]
    for hop in pipeline_bench.HOPS:
        h = lat[hop]
        assert 0.0 < h["p50"] <= h["p99"] <= h["max"], (hop, h)
    # Arrival along the path, frame by frame: targets, then commands, then states. (Not the hops' p50s against
    # each other: under load a hop drops frames, and the p50 over the frames that got through can sit below the
    # hop before's: 1.09 ms against 1.41 in one full run at load ~3.)
    for hop in pipeline_bench.HOPS[1:]:
        assert res["hop_increment_ms"][hop]["p50"] > 0.0, (hop, res["hop_increment_ms"][hop])
    assert res["latency_ms"] == lat["sim"]
    assert set(res["hop_ms"]) == set(pipeline_bench.HOPS)
    # Each stand-in ran as its own process, announced as the service it replaces, and worked.
    for hop in pipeline_bench.HOPS:
        assert res["cpu_ms_per_frame"][hop] > 0.0, res["cpu_ms_per_frame"]
        assert res["idle_cpu_ms_per_s"][hop] is not None
        assert hop in res["drops"]
    status = {s["counts"].get("published.targets", 0) for s in res["service_status"].values()}
    assert max(status) >= res["received"]
    retarget = next(v for k, v in res["service_status"].items() if "/retarget/" in k)
    assert retarget["counts"]["received.frames"] >= res["received"]
    # Not the real retarget: that one reports its calibration.
    assert "calibrated" not in retarget["extra"]
    assert res["drops_total"] >= 0
