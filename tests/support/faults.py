"""Fault injection on the real stack: crash/restart, solver swap, input bursts.

Each scenario runs real processes on loopback (router, retarget, solver, sim, the
demo clip looping through ``mimic publish``), injects one fault and returns the
measured figures as a dict; the tests in tests/reliability assert on them. Run as a
script to print the figures as JSON::

    .venv/bin/python -m tests.support.faults crash      # kill -9 + restart each service
    .venv/bin/python -m tests.support.faults swap       # solver swap mid-stream
    .venv/bin/python -m tests.support.faults burst --rate 10000 --duration 10
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import itertools
import json
import subprocess
import sys
import tempfile
import time

import numpy as np

from services.evaluation.soak import FramePublisher, dropped_counts, latency_windows
from services.launcher.local_stack import LocalStack
from services.solver.core import SolverConfig
from shared.bus import bus_args, free_port, open_session, query
from shared.keys import Keys
from shared.robot.pinocchio_model import build_robot_model
from tests.support.observer import Observer, StateSample

PIPELINE = ("retarget", "solver", "sim")
STATUS_PERIOD = 0.2  # [s] every service's status period in these scenarios
SOLVER_DT = 1.0 / SolverConfig().rate  # [s] one tick at mimic solve's default rate
#: Measured q may lead the rate-limited servo target a little (PD tracking overshoot) [rad/s].
VEL_TOL = 0.5


def vmax_by_joint() -> dict[str, float]:
    r = build_robot_model()
    return dict(zip(r.joint_names, r.vmax.tolist(), strict=True))


@contextlib.contextmanager
def running_stack(names=PIPELINE, extra: dict[str, list[str]] | None = None, clip_loop: bool = True):
    """Router + ``names`` (+ the demo clip looping through ``mimic publish``), frames flowing.

    Yields:
        (stack, observer), after the first RobotState carrying a mocap frame arrived.
    """
    from services.ingest.demo_motion import generate_demo_clips

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = f"rel{endpoint.rsplit(':', 1)[1]}"
    with LocalStack(session, endpoint, status_period=STATUS_PERIOD) as stack:
        stack.start_all(list(names), extra)
        obs = Observer(endpoint, session)
        try:
            if clip_loop:
                # The ellipse: both hands move without touching (box_lift's hand contacts make the
                # simulated joints bounce past vmax, which would blur the jump checks).
                clip = generate_demo_clips(tempfile.mkdtemp(prefix="mimic-rel-"))[1]
                stack.start(
                    "publish",
                    argv=["mimic", "publish", str(clip), "--loop", "--status-period", str(STATUS_PERIOD)],
                )
                obs.wait_until(
                    lambda: any(s.seq > 0 and not s.holding for s in obs.states[-50:]), 60, "frames reaching the sim"
                )
            # The observer lives in this (test) process: its Zenoh callbacks need the interpreter, and a full
            # garbage collection over everything a long pytest run has built (a gen-2 pass over the imports alone
            # takes ~0.1 s here) stalls them, which reads as the stack pausing. Objects made before the scenario
            # are set aside from collection while it runs (the stack's processes are not affected).
            gc.collect()
            gc.freeze()
            yield stack, obs
        finally:
            gc.unfreeze()
            obs.close()


def max_state_velocity(states: list[StateSample], vmax: np.ndarray) -> tuple[float, int]:
    """Largest |dq| / d(sim_time) - vmax over consecutive states of one sim [rad/s], and the pair count.

    A new sim process (sim_time starting again) begins a new sequence.
    """
    worst, pairs = -np.inf, 0
    for a, b in itertools.pairwise(states):
        dt = b.sim_time - a.sim_time
        if dt <= 0:  # a restarted sim, or a repeated publication
            continue
        pairs += 1
        worst = max(worst, float(np.max(np.abs(b.q - a.q) / dt - vmax)))
    return worst, pairs


#: Time after the watchdog hold starts from which the joints must be still [s].
HOLD_SETTLE_S = 0.5


def crash_restart(stack: LocalStack, obs: Observer, victim: str) -> dict:
    """``kill -9`` one service, check the others and the watchdog, restart it, time the resume."""
    others = [n for n in PIPELINE if n != victim]
    with obs.lock:
        last_seq = obs.states[-1].seq
    pids_before = stack.pids()
    t_kill_ns = time.time_ns()
    t_kill = time.monotonic()
    stack.kill9(victim)
    name = f"{victim}/main"
    t_gone = obs.wait_until(
        lambda: any(t >= t_kill and k == "DELETE" and n == name for t, k, n in obs.alive_events), 5, f"{name} DELETE"
    )
    res: dict = {"victim": victim, "liveliness_delete_s": t_gone - t_kill}
    # Watch the stack without the victim for a while.
    time.sleep(1.2)  # long enough for the held joints to settle (HOLD_SETTLE_S)
    t_watch = time.monotonic()
    res["others_running"] = {n: stack.running(n) and stack.pid(n) == pids_before[n] for n in others}
    with obs.lock:
        res["others_status_after_kill"] = {
            n: sum(1 for t in obs.status_times.get(f"{n}/main", []) if t > t_kill + 0.3) for n in others
        }
        res["others_alive"] = {n: f"{n}/main" in obs.alive for n in others}
        after = [s for s in obs.states if s.t >= t_kill]
    if victim == "solver":
        first_hold = next((s for s in after if s.holding), None)
        res["hold_after_s"] = None if first_hold is None else first_hold.t - t_kill
        held = [s for s in after if s.holding]
        res["held_states"] = len(held)
        res["hold_q_drift_rad"] = float(max(np.max(np.abs(s.q - held[0].q)) for s in held)) if held else None
        # Once the servos settled on the held target, the joints stay put. The slowest are the
        # waist joints carrying the torso: after a hold from 4 rad/s (SimCore, lock-step) they
        # still move 0.004 rad after 0.1 s, 0.0013 after 0.3 s, 0.0001 after 0.5 s; CI saw 0.02
        # after 0.1 s following faster motion.
        settled = [s for s in held if s.sim_time >= held[0].sim_time + HOLD_SETTLE_S]
        res["hold_q_drift_settled_rad"] = (
            float(max(np.max(np.abs(s.q - settled[0].q)) for s in settled)) if settled else None
        )
    if victim != "sim":
        res["states_during_outage"] = sum(1 for s in after if s.t < t_watch)
    res["new_frames_during_outage"] = sum(1 for s in after if s.t0 > t_kill_ns)

    # Restart: the same command as a new process.
    log_mark = len(stack.output(tail=None))
    t_restart = stack.start(victim)
    t_alive = obs.wait_until(
        lambda: any(t >= t_restart and k == "PUT" and n == name for t, k, n in obs.alive_events), 60, f"{name} back"
    )
    t_resume = obs.wait_until(
        lambda: any(s.t >= t_alive and s.t0 > t_kill_ns and not s.holding for s in obs.states[-200:]),
        20,
        f"stream resumed after restarting {victim}",
    )
    if victim == "retarget":
        # The operator is moving now: the restarted retarget must keep the session's calibration.
        res["retarget_calibration_restored"] = "calibration restored from" in stack.output(tail=None)[log_mark:]
    res["startup_s"] = t_alive - t_restart  # process start until its liveliness token
    res["resume_after_alive_s"] = t_resume - t_alive  # token until a new frame reached the robot state
    res["resume_after_restart_s"] = t_resume - t_restart
    time.sleep(0.5)
    with obs.lock:
        res["seq_advanced"] = obs.states[-1].seq > last_seq
        states = [s for s in obs.states if s.t >= t_kill - 0.5]
        if victim == "solver":
            first = next((c for c in obs.commands if c.t >= t_alive and c.solver_id == "main"), None)
            before = [s for s in obs.states if s.t <= (first.t if first else 0)]
            ref = before[-1].q if before else None
            res["new_solver_first_cmd_vs_state_rad"] = (
                None if first is None or ref is None else float(np.max(np.abs(first.q - ref)))
            )
            new = [c for c in obs.commands if c.t >= t_alive and c.solver_id == "main"]
            # Per solver tick: a command the observer missed under load (the bus keeps the newest) must not
            # read as one step of two or three ticks.
            steps = [
                float(np.max(np.abs(b.q - a.q))) / max(1, round((b.t_cmd - a.t_cmd) / SOLVER_DT))
                for a, b in itertools.pairwise(new)
            ]
            res["new_solver_max_cmd_step_rad"] = max(steps, default=None)
            new_log = stack.output(tail=None)[log_mark:]
            res["new_solver_started_from_rest"] = "starting from the rest pose" in new_log
            res["new_solver_reanchored"] = "re-initialised from the first robot state" in new_log
    vmax = np.full(states[0].q.shape, max(vmax_by_joint().values())) if states else np.zeros(0)
    excess, pairs = max_state_velocity(states, vmax)
    res["state_velocity_excess_rad_s"] = excess
    res["state_pairs"] = pairs
    return res


def swap_solver(stack: LocalStack, obs: Observer, algo: str = "wqp") -> dict:
    """Second solver ``b`` with another algorithm, switch the sim to it, stop the first one."""
    t_b = stack.start(
        "solver-b",
        argv=["mimic", "solve", "--algo", algo, "--id", "b", "--status-period", str(STATUS_PERIOD)],
    )
    stack.wait_alive(["solver/b"], timeout=60)
    obs.wait_until(lambda: any(c.solver_id == "b" and c.t > t_b for c in obs.commands[-400:]), 10, "commands from b")
    # Switch once b is past its start-up (imports, model build, first solves): on 2 cores that burst
    # starves the running solver for up to ~0.2 s (the sim holds), a cost of starting a process on a
    # full machine, not of the switch. It is reported apart (startup_*), the switch window after it.
    time.sleep(1.5)
    t_switch = time.monotonic()
    reply = query(obs.z, obs.keys.sim_follow, b"b")
    t_reply = time.monotonic()
    obs.wait_until(lambda: any(s.t > t_switch and s.solver_id == "b" for s in obs.states[-50:]), 5, "sim follows b")
    time.sleep(0.5)
    t_stop = time.monotonic()
    code = stack.sup.stop("solver")  # SIGTERM: the first one goes away cleanly
    time.sleep(1.5)
    t_end = time.monotonic()
    with obs.lock:
        startup = [s for s in obs.states if t_b <= s.t < t_switch - 0.5]
        states = [s for s in obs.states if t_switch - 0.5 <= s.t <= t_end]
        after_stop = [s for s in obs.states if s.t > t_stop]
    seqs = [s.seq for s in states]
    # Largest wall-clock gap between states that carry a new mocap frame (the stream's "drop").
    fresh_t = [s.t for i, s in enumerate(states) if i == 0 or s.seq != seqs[i - 1]]
    gaps = np.diff(fresh_t) if len(fresh_t) > 1 else np.array([np.inf])
    # Sim-time steps between states published one after the other (consecutive sample numbers): how
    # long the sim itself paused. States lost on the way (the router starved of CPU) are counted apart.
    numbered = [(a, b) for a, b in itertools.pairwise(states) if a.number is not None and b.number is not None]
    sim_dt = np.array([b.sim_time - a.sim_time for a, b in numbered if b.number == a.number + 1])
    lost = sum(b.number - a.number - 1 for a, b in numbered if b.number > a.number)
    vmax = np.full(states[0].q.shape, max(vmax_by_joint().values()))
    excess, pairs = max_state_velocity(states, vmax)
    return {
        "algo_b": algo,
        "follow_reply": reply.decode(errors="replace") if isinstance(reply, bytes) else str(reply),
        "query_s": t_reply - t_switch,
        "first_solver_exit_code": code,
        "states": len(states),
        "holding_states": sum(s.holding for s in states),
        "startup_holding_states": sum(s.holding for s in startup),
        "startup_max_gap_state_s": float(np.max(np.diff([s.t for s in startup]))) if len(startup) > 1 else None,
        "max_gap_new_frame_s": float(np.max(gaps)),
        "max_gap_state_s": float(np.max(np.diff([s.t for s in states]))),
        "max_gap_sim_time_s": float(np.max(sim_dt)) if sim_dt.size else None,
        "states_lost_on_the_way": lost,
        "state_velocity_excess_rad_s": excess,
        "state_pairs": pairs,
        "followed_after_stop": sorted({s.solver_id for s in after_stop}),
        # Where things happened, relative to the follow switch [s] (the stop is at stop_at_s).
        "stop_at_s": t_stop - t_switch,
        "holding_at_s": [round(s.t - t_switch, 3) for s in states if s.holding][:20],
        "max_gap_state_at_s": float(states[int(np.argmax(np.diff([s.t for s in states])))].t - t_switch),
        "new_frames_after_stop": len({s.seq for s in after_stop}),
    }


def burst(stack: LocalStack, obs: Observer, rate: float, duration: float) -> dict:
    """Publish HumanFrames at ``rate`` Hz for ``duration`` s from a process of its own; latency per second.

    The publisher must not share the observer's process: at 10 kHz it holds the observer's GIL
    and the observer would stamp each RobotState hundreds of ms late (the latency measured would
    be the harness's own).
    """
    argv = [sys.executable, "-m", "tests.support.faults", "publish", "--endpoint", stack.endpoint]
    argv += ["--session", stack.session, "--rate", str(rate), "--duration", str(duration)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=duration + 60, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"burst publisher failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    pub = json.loads(done.stdout)
    t0_ns = {int(k): v for k, v in pub["t0_ns"].items()}
    time.sleep(1.0 + 2 * STATUS_PERIOD)
    with obs.lock:
        arrival = dict(obs.first_state_ns)
        status = dict(obs.status)
    windows = latency_windows(t0_ns, arrival, pub["t_start_ns"])
    full = [w for w in windows if "p99" in w and w["sent"] > rate / 2]  # whole seconds that reached the robot
    counts = dict(status["retarget/main"].counts) if "retarget/main" in status else {}
    return {
        "rate_hz": rate,
        "achieved_rate_hz": pub["achieved_rate_hz"],
        "sent": pub["sent"],
        "reached": sum(w["reached"] for w in windows),
        "windows": windows,
        "first_s": full[0] if full else None,
        "last_s": full[-1] if full else None,
        "dropped": dropped_counts(status),
        "retarget_counts": counts,
        "alive": {n: stack.running(n) for n in PIPELINE},
        # Sent but neither received by retarget nor seen as a gap: 0 in 3 quiet runs, 3462 in one
        # full-suite run (not understood yet; a lost tail has no later frame to reveal it).
        "unseen_by_retarget": pub["sent"] - counts.get("received.frames", 0) - counts.get("gaps.frames", 0),
    }


def publish(endpoint: str, session: str, rate: float, duration: float) -> dict:
    """The burst publisher's side of :func:`burst`: frames sent and their t0 [ns] by seq."""
    z = open_session(bus_args(connect=[endpoint], session=session))
    try:
        pub = FramePublisher(z, Keys(session), rate)
        time.sleep(0.5)  # let the router learn the publisher's route before the first frame
        # One frame first, and time to take it: a subscriber counts gaps from the first number it
        # sees, so frames lost before that (its ring overflowing at the very start) would be unseen.
        pub.publish_one(0)
        time.sleep(0.3)
        t_start_ns = time.time_ns()
        pub.run(duration, first=1)
        time.sleep(0.5)  # closing at once would discard the frames still queued in this session
    finally:
        z.close()
    return {"sent": pub.sent, "achieved_rate_hz": pub.achieved_rate, "t_start_ns": t_start_ns, "t0_ns": pub.t0_ns}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    p.add_argument("scenario", choices=("crash", "swap", "burst", "publish"))
    p.add_argument("--rate", type=float, default=10000.0, help="burst: frames per second [Hz]")
    p.add_argument("--duration", type=float, default=10.0, help="burst: seconds")
    p.add_argument("--endpoint", help="publish: router endpoint of the stack under test")
    p.add_argument("--session", help="publish: its bus session")
    a = p.parse_args()
    if a.scenario == "publish":
        out = publish(a.endpoint, a.session, a.rate, a.duration)
    elif a.scenario == "burst":
        with running_stack(clip_loop=False) as (stack, obs):
            out = burst(stack, obs, a.rate, a.duration)
    elif a.scenario == "swap":
        with running_stack() as (stack, obs):
            out = swap_solver(stack, obs)
    else:
        with running_stack() as (stack, obs):
            out = {v: crash_restart(stack, obs, v) for v in PIPELINE}
    sys.stdout.write(json.dumps(out, indent=2, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
