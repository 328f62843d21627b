"""Solver swap mid-stream (issue 8, item 4).

While the demo clip flows through the real stack, a second solver process with
another algorithm (``--algo wqp --id b``) starts, the sim is switched to it through
its follow queryable, and the first solver is stopped: the robot state carries on
without a joint jump, the sim never pauses, and it holds (its watchdog: no command
for 100 ms) only briefly. Two solvers at 500 Hz beside the sim, retarget, router and
publisher overload 2 cores, so brief holds happen: `python -m tests.support.faults
swap` prints the figures (8 quiet runs on this machine: 0-13 holding states around
the switch, 0-35 during b's start-up, reported apart; 0.10-0.33 s longest wall-clock
gap between states reaching the observer).
"""

from __future__ import annotations

import json

import pytest

from tests.support.faults import running_stack, swap_solver, vmax_by_joint

pytestmark = [pytest.mark.integration, pytest.mark.slow]
VMAX = max(vmax_by_joint().values())
WATCHDOG = 0.1  # [s] mimic sim default
STATE_VEL_TOL = 1.5 * VMAX  # see test_crash_restart: PD tracking overshoot, far below any jump


def test_swap_to_another_algorithm_mid_stream():
    with running_stack() as (stack, obs):
        r = swap_solver(stack, obs, algo="wqp")
        ctx = json.dumps(r, indent=1, default=float) + "\n" + stack.output(3000)
        assert '"b"' in r["follow_reply"] or "b" in r["follow_reply"], ctx
        assert r["first_solver_exit_code"] == 0, ctx
        # After the first solver is gone the sim follows b, and new frames still arrive.
        assert r["followed_after_stop"] == ["b"], ctx
        assert r["new_frames_after_stop"] > 5, ctx
        # Holds only briefly around the switch (from 0.5 s before it; b's start-up burst is reported
        # apart as startup_*): at most 0.2 s of holding in all, 3x the worst quiet run (13 states).
        assert r["holding_states"] <= 40, ctx
        # The sim itself never paused for a watchdog period: sim time between states it published one
        # after the other (states Zenoh dropped while the router was starved are reported apart: a
        # quiet run lost 26 in a row once, a 0.13 s hole seen from outside) ...
        assert r["max_gap_sim_time_s"] <= WATCHDOG, ctx
        # ... and what reached us never paused for long (wall clock; worst quiet run 0.33 s).
        assert r["max_gap_state_s"] < 5 * WATCHDOG, ctx
        assert r["state_pairs"] > 50, ctx
        assert r["state_velocity_excess_rad_s"] < STATE_VEL_TOL, ctx
