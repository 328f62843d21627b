"""`mimic up --robot models/tita_piper.toml`: a real clip through retarget -> wbqp-accel -> MuJoCo -> Rerun.

The stack is the compose file's, started by :class:`LocalStack` with ``MIMIC_ROBOT`` (what
``mimic up --robot FILE`` sets); the clip is the real one whose right hand reaches forward the
furthest (measured from the clips at run time, :mod:`tests.support.reach`).
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from services.launcher.local_stack import LocalStack
from services.launcher.stack import COMPOSE_FILE, load_stack
from services.logger.rrd_summary import summarize
from shared.bus import bus_args, open_session
from shared.keys import Keys
from shared.messages import RobotState, TaskTargets
from shared.paths import REPO_ROOT
from shared.robot.profile import DEFAULT_PROFILE
from tests.support.reach import forward_reach_clip

ROBOT = "models/tita_piper.toml"
SERVICES = ("retarget", "solver", "sim", "logger")
#: Mean distance [m] of the simulated gripper from the newest hand target while the clip plays.
#: Measured 0.133 m through this stack (byebye_happy, the clip picked here, load average ~6 on 2
#: cores) and 0.075 m without the bus (python -m services.wbc.clip_replay): the reference filter and
#: the torso's acceleration bound let a fast human hand (1-2 m/s, 1.5x forward) lead by design,
#: and the bus adds its latency. Bound: ~2x the stack figure.
HAND_MEAN_M = 0.25
#: The torso must roll at least this far forward [m] (0.3-0.46 m measured without the bus).
TORSO_FORWARD_M = 0.1

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_compose_default_robot_is_the_profile_default():
    """The compose file's ``${MIMIC_ROBOT:-...}`` fallback names the same robot as the code's default."""
    for name in SERVICES:
        argv = load_stack(COMPOSE_FILE, {}).get(name).command
        assert argv[argv.index("--robot") + 1] == DEFAULT_PROFILE


def test_robot_reaches_every_service_that_needs_it(tmp_path):
    stack = load_stack(COMPOSE_FILE, {"MIMIC_ROBOT": "/x/tita.toml"})
    for name in SERVICES:
        argv = stack[name].command
        assert argv[argv.index("--robot") + 1] == "/x/tita.toml", name


@pytest.mark.parametrize("robot", ["no_such_robot", "tests/no_such_file.toml", "BAD"])
def test_mimic_up_with_a_bad_robot_is_one_line(tmp_path, robot):
    if robot == "BAD":
        robot = str(tmp_path / "bad.toml")
        (tmp_path / "bad.toml").write_text('kind = "wheeled_legged_arm"\n[frames\n')
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.cli",
            "up",
            "--robot",
            robot,
            "--session",
            "h17bad",
            "--endpoint",
            "tcp/127.0.0.1:9",
        ],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 1
    assert len(lines) == 1 and "robot profile" in lines[0], proc.stderr


def test_real_forward_reach_rolls_the_torso_forward_through_the_stack(bvh_clips, zenoh_endpoint, tmp_path):
    clip, reach = forward_reach_clip(bvh_clips)
    assert reach > 0.15, f"no clip reaches forward: best {clip.name} {reach:.3f} m"
    session = f"h17e2e{zenoh_endpoint.rsplit(':', 1)[1]}"
    keys = Keys(session)
    states: list[RobotState] = []
    targets: list[tuple[float, np.ndarray]] = []
    lock = threading.Lock()
    rrd = tmp_path / "tita.rrd"
    with LocalStack(session, zenoh_endpoint, env={"MIMIC_ROBOT": ROBOT}, status_period=0.2) as stack:
        stack.start_all(SERVICES, extra={"logger": ["--rrd", str(rrd), "--overwrite"]}, timeout=180)
        z = open_session(bus_args(connect=[zenoh_endpoint], session=session))
        try:

            def on_state(s):
                with lock:
                    states.append(RobotState.decode(s.payload.to_bytes()))

            def on_targets(s):
                msg = TaskTargets.decode(s.payload.to_bytes())
                with lock:
                    targets.append((time.monotonic(), msg.targets["right_wrist"].p.copy()))

            z.declare_subscriber(keys.sim_state, on_state)
            z.declare_subscriber(keys.targets, on_targets)
            time.sleep(1.0)
            with lock:
                x0 = states[-1].q[0] if states else None
            assert x0 is not None, stack.output()
            stack.start("play", argv=["mimic", "publish", str(clip), "--wait-subscriber", "10"], service=False)
            errs = []
            while stack.running("play"):
                time.sleep(0.05)
                with lock:
                    if targets and states:
                        errs.append(float(np.linalg.norm(states[-1].frames["right_wrist"].p - targets[-1][1])))
            time.sleep(1.5)
            with lock:
                xs = np.array([s.q[0] for s in states])
                n_targets = len(targets)
        finally:
            z.close()
        codes = stack.stop(timeouts={"logger": 90.0})
    assert n_targets > 10 and errs, stack.output()
    forward = float(xs.max() - x0)
    mean_err = float(np.mean(errs))
    print(f"clip {clip.name} (reach {reach:.3f} m): torso forward {forward:.3f} m, hand error mean {mean_err:.3f} m")
    assert forward > TORSO_FORWARD_M, stack.output()
    assert mean_err < HAND_MEAN_M, stack.output()
    assert all(code in (0, None) or code == -15 for code in codes.values()), codes
    drawn = summarize(rrd)
    assert "/world/robot/sim/torso_geom" in drawn.static  # the robot's primitives ...
    assert drawn.rows.get("/world/robot/sim/torso_geom", 0) > 0  # ... posed while it moved
