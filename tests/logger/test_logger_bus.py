"""The logger on a real Zenoh bus (loopback): every published message reaches the .rrd."""

from __future__ import annotations

import time

import pytest
import rerun as rr
from test_rerun_logger import N, make_sequence

from services.logger.node import LoggerNode
from services.logger.rerun_logger import RerunLogger
from services.logger.rrd_summary import summarize
from shared.bus import ServiceRunner, bus_args, open_session
from shared.messages import peek_type

pytestmark = pytest.mark.integration
SESSION = "logtest"


def _key(keys, payload: bytes) -> str:
    kind = peek_type(payload)
    return {
        "HumanFrame": keys.mocap_frame,
        "TaskTargets": keys.targets,
        "RobotState": keys.sim_state,
        "ServiceStatus": keys.status("solver"),
    }.get(kind) or keys.command("main")


def test_logger_records_everything_published_on_the_bus(tmp_path, zenoh_endpoint):
    hub = open_session(bus_args(mode="router", listen=[zenoh_endpoint], connect=[]))
    rrd = tmp_path / "bus.rrd"
    rec = rr.RecordingStream("mimic_test")
    rec.save(str(rrd))
    logger = RerunLogger(rec, None, skeleton_rate=0.0)  # meshes are covered by the direct test
    payloads = make_sequence()
    try:
        args = bus_args(connect=[zenoh_endpoint], session=SESSION, status_period=0.2)
        with ServiceRunner("logger", args, install_signals=False) as svc:
            node = LoggerNode(logger, svc, queue_size=4096)
            with open_session(bus_args(connect=[zenoh_endpoint], session=SESSION)) as z:
                keys = svc.keys
                pubs = {}
                time.sleep(0.5)  # let the subscription propagate through the router
                for p in payloads:
                    k = _key(keys, p)
                    pub = pubs.get(k) or pubs.setdefault(k, z.declare_publisher(k))
                    pub.put(p)
                    time.sleep(0.001)
                deadline = time.monotonic() + 10
                while logger.counts.get("HumanFrame", 0) < N and time.monotonic() < deadline:
                    time.sleep(0.05)
            node.close()
            logger.flush_error()
            node.update_status()
            assert svc.status.extra["skipped"] == 0
    finally:
        hub.close()
    rec.flush()
    rec.disconnect()
    # The logger also saw its own status (and the commands of "alt", published on main's key).
    assert logger.counts["HumanFrame"] == N and logger.counts["TaskTargets"] == N
    assert logger.counts["RobotState"] == N and logger.counts["decimated"] == 2 * N
    s = summarize(rrd)
    assert s.rows["/world/operator/skeleton"] == N
    assert s.rows["/metrics/error_cm"] == N
    assert s.rows["/metrics/solve_ms/main"] == N and s.rows["/metrics/solve_ms/alt"] == N
    assert s.rows["/metrics/latency_ms/targets"] == N
    assert s.rows.get("/metrics/skipped_by_design/solver", 0) >= 1
