"""The whole stack as real processes (`mimic up`) on a real recorded clip."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from shared.paths import REPO_ROOT

REPO = REPO_ROOT
CLIP = "dataset-1_bye_normal_001.bvh"
#: Mean wrist error [cm] of the simulated robot on CLIP through the whole stack, unloaded machine
#: (measured 1.34 cm; 1.75 cm with the code before the issue-13 solver changes). It is the error of
#: the simulated robot against each frame's target as it arrives, lag and servo compliance included,
#: not the kinematic eval figure (~0.07 cm); the old bound, 5.0 cm, was ~4x it.
WRIST_MEAN_CM = 1.34
pytestmark = [pytest.mark.integration, pytest.mark.slow]


def _descendants(pid: int) -> set[int]:
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        parents[int(stat.parent.name)] = int(fields[1])
    out, frontier = set(), {pid}
    while frontier:
        kids = {p for p, pp in parents.items() if pp in frontier}
        frontier = kids - out
        out |= kids
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_real_clip_flows_through_the_whole_stack(bvh_clips, mocap_sources, tmp_path, zenoh_endpoint):
    clip = next(c for c in bvh_clips if c.name == CLIP)
    summary_path = tmp_path / "summary.json"
    argv = [
        sys.executable,
        "-m",
        "services.cli",
        "up",
        "--demo",
        "--clips",
        str(clip),
        "--session",
        f"e2e{zenoh_endpoint.rsplit(':', 1)[1]}",
        "--endpoint",
        zenoh_endpoint,
        "--summary",
        str(summary_path),
        "--only",
        "retarget",
        "--only",
        "solver",
        "--only",
        "sim",
    ]
    proc = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen: set[int] = set()
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    while proc.poll() is None:
        seen |= _descendants(proc.pid)
        time.sleep(0.2)
    reader.join(5)
    out = "".join(lines)
    assert proc.returncode == 0, out[-4000:]
    s = json.loads(summary_path.read_text())

    frames = sum(v["out"] for k, v in s["services"].items() if k.startswith("publish/"))  # one status per clip
    assert frames == mocap_sources.frames(CLIP)  # every frame of the clip published
    # Every published frame came through retarget, and reached the simulated robot.
    assert s["services"]["retarget/main"]["in"] == frames
    assert s["services"]["retarget/main"]["out"] == frames
    assert s["services"]["retarget/main"]["rejected"] == 0
    # Downstream of retarget the newest frame wins: a frame superseded before the solver's next
    # tick is skipped and counted, never silently lost.
    reached = s["latency_ms"]["samples"]
    skipped = s["services"]["solver/main"]["counts"].get("dropped.targets", 0) + s["services"]["sim/main"][
        "counts"
    ].get("dropped.commands", 0)
    assert reached >= 0.9 * frames, s["latency_ms"]
    assert frames - reached <= skipped
    # The robot follows: wrist error measured on the simulated robot (last state of each frame).
    # Bound: twice the figure of an unloaded run (WRIST_MEAN_CM). On a machine so loaded that the
    # stack falls behind real time the error grows (6.1 cm at load 20 on 2 cores), but then fewer
    # than 90 % of the frames reach the robot and the check above fails first (46 of 111 there).
    assert s["wrist_err_cm"]["mean"] < 2 * WRIST_MEAN_CM, s["wrist_err_cm"]
    # No joint ever commanded past its limits; the simulated joints stay within them
    # up to the servo's compliance.
    assert s["max_command_limit_excess_rad"] <= 1e-9
    assert s["max_joint_limit_excess_rad"] < 0.05
    # Clean shutdown: every service exited 0 and no process is left behind.
    assert all(code == 0 for code in s["exit_codes"].values()), s["exit_codes"]
    assert len(seen) >= 4
    time.sleep(0.5)
    assert not [p for p in seen if _alive(p)], "processes left behind"
