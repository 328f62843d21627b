"""The pipeline bench's drop accounting: per service, per stream, mailbox and Zenoh-lost apart."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from services.evaluation.pipeline_bench import cpu_seconds, path_drops, service_drops, solver_rate
from services.solver.core import SolverConfig
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


def test_cpu_seconds_tells_a_busy_process_from_a_sleeping_one():
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    idle = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        time.sleep(0.5)  # both past their start-up
        b0, i0 = cpu_seconds(busy.pid), cpu_seconds(idle.pid)
        time.sleep(1.0)
        b1, i1 = cpu_seconds(busy.pid), cpu_seconds(idle.pid)
    finally:
        busy.kill()
        idle.kill()
        busy.wait()
        idle.wait()
    # A spinning process gets a good part of a core even on a loaded 2-core machine; a sleeping one none.
    assert b1 - b0 > 0.1, (b0, b1)
    assert i1 - i0 < 0.02, (i0, i1)
    assert cpu_seconds(busy.pid) is None  # gone: /proc cannot say
    assert 0.0 <= cpu_seconds(os.getpid()) < 1e6


def test_bench_solver_ticks_at_the_input_rate_up_to_the_shipped_rate():
    shipped = SolverConfig().rate
    assert solver_rate(200.0) == 200.0  # event ticks: one per target, no clock ticks in between
    assert solver_rate(1000.0) == shipped  # above it the targets tick it anyway
