"""The lock-up recovery on the real kick_normal clip: it leads the right arm out of the elbow-hyperextension lock
within a bound, keeping level 1, and does not fire on the speed-saturated kicks before it.

The locks were recorded with the wrist point on the hand link (the G1 profile before session 15). With the shipped
wrist point, the pitch axis, the arm does not run into them (from rest, the right elbow 0.26 cm off over 2.8-3.0 s
without the recovery, against 20.7 cm; from Q_LOCK the wrist target is another point): the tests run on that
profile (``g1_with_the_hand_as_wrist_point``), since what they check is the recovery, not the profile."""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import SolverConfig, SolverCore
from services.solver.recovery import LockupRecovery, RecoveryConfig
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import load_profile
from tests.support.lockstep import clip_targets_until, step_through
from tests.support.profiles import g1_with_the_hand_as_wrist_point

KICK = "dataset-1_kick_normal_001.bvh"
RATE = 500.0
#: [s] of clip: the lock-up window (the right arm's state at LOCK_T below, then the clip's targets to LOCK_END).
LOCK_T, LOCK_END = 3.2, 4.4
#: The solver's joints [rad] at LOCK_T of kick_normal with ``saturation_weight=2`` (h12k): right elbow at its
#: hyperextension stop (2.06), right wrist roll at its stop (-1.94), shoulder yaw -1.63 (the folded branch the
#: elbow target asks for has it near +0.95), waist roll 0.41 and pitch -0.23; the wrist on its target, the elbow
#: 9 cm off. From here the shipped hierarchy meets the wrist and leaves the elbow 9-10 cm off for seconds.
Q_LOCK = np.array([
    -0.4464, 0.4075, -0.2295,
    1.3169, -0.0363, -0.1701, 0.1485, -0.2252, 0.0207, 0.0925,
    -1.1204, 0.6272, -1.6256, 2.0644, -1.9422, -1.2845, 0.2844,
])  # fmt: skip
#: The solver of the time the locks were recorded with (where a test needs the lock itself): the centring band 0.25
#: (0.15 since session 17) and the wrist orientations at gain 30, cost 0.3 (200 and 0.045 since session 18, the same
#: trade of errors, a faster hand; the kick lock then loosens: elbow min 7.2 cm without the recovery).
OF_THE_TIME = {"range_centring_band": 0.25, "orientation_gain": 30.0, "wrist_orientation_cost": 0.3}


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    return build_robot_model(load_profile(g1_with_the_hand_as_wrist_point(tmp_path_factory.mktemp("profiles"))))


@pytest.fixture(scope="module")
def kick(robot):
    # Q_LOCK was recorded on the targets as published before the trunk push was the default (session 13): with
    # the push the right wrist target, 2.5 cm inside the chest there, sits 4.6 cm in front of it, and from Q_LOCK
    # the elbow is still 2.8 cm off at 1 s (falling to 0.1 cm by the window's end): another scenario.
    # The locks were recorded on targets from each arm's own workspace draw (before session 21: per_arm_draws).
    return clip_targets_until(KICK, robot, LOCK_END, retarget={"trunk_clearance": False}, per_arm_draws=True)


def _right_arm_run(robot, frames, core: SolverCore) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t [s], right elbow error [cm], right wrist error [cm]) per tick of ``core`` through ``frames``, errors
    against the targets the tick aimed at; also checks every command is within the joint limits."""
    rows = []
    stamps = np.array([f.hdr.stamp for f in frames]) - frames[0].hdr.stamp
    j = 0
    for k in range(int(stamps[-1] * RATE) + 1):
        t = k / RATE
        msg = None
        while j < len(frames) and stamps[j] <= t + 1e-9:
            msg, j = frames[j], j + 1
        cmd = core.step(msg, None, t)
        assert np.all(cmd.q >= robot.lower - 1e-9) and np.all(cmd.q <= robot.upper + 1e-9)
        poses = robot.frame_poses(cmd.q)
        e = np.linalg.norm(poses["right_elbow"][0] - core.elbow_tasks[1].p_target)
        w = np.linalg.norm(poses["right_wrist"][0] - core.wrist_tasks[1].p_target)
        rows.append((t, 100 * e, 100 * w))
    a = np.array(rows)
    return a[:, 0], a[:, 1], a[:, 2]


def test_recovery_leads_the_arm_out_of_the_kick_lock_keeping_the_wrist(robot, kick):
    t0 = kick[0].hdr.stamp
    frames = [f for f in kick if f.hdr.stamp - t0 >= LOCK_T]
    out = {}
    for recovery in (False, True):
        # Self-collision rows off: the recovery's own route, timed. With them (shipped), next test. The solver of the
        # time: with the shipped centring band 0.15 the lock is looser (elbow min 7.4 cm without the recovery).
        core = SolverCore(robot, SolverConfig(recovery=recovery, self_collision=False, **OF_THE_TIME))
        core.reset(Q_LOCK)
        out[recovery] = (*_right_arm_run(robot, frames, core), core.counts["recoveries"])
    t, el, wr_locked, _ = out[False]
    # Without the recovery the lock holds: the elbow stays 9-10 cm off (measured min 8.7) for the whole 1.2 s,
    # the wrist on its target (p99 0.21 cm).
    assert el.min() > 8.0 and np.percentile(wr_locked, 99) < 0.3, (el.min(), np.percentile(wr_locked, 99))
    t, el, wr, events = out[True]
    # With it: one recovery, detected after its 0.1 s window; the arm swings through the straight elbow to the
    # folded branch (the elbow error rises to ~19 cm on the way) and is back under 3 cm 0.6 s after the window
    # opened (measured 0.49 s with the G1's 8 rad/s arms; 0.79 s at 4, the elbow joint travelling 2 rad), under 1 cm
    # from 0.85 s on (measured max 0.86) ...
    assert events == 1
    back = t[np.argmax(el < 3.0)]
    assert el[t < 0.1].min() > 8.0 and back <= 0.7, back
    assert el[t >= 0.85].max() < 1.0, el[t >= 0.85].max()
    # ... and level 1 keeps its strict priority throughout: the wrist as close as in the lock (p99 0.168 against
    # 0.171 cm, max 0.248 against 0.247; 0.183 p99 with every joint at 6 rad/s: each tick strict, a fast swing's
    # second-order drift aside, see test_wrist_only_solver.py).
    assert np.percentile(wr, 99) <= np.percentile(wr_locked, 99) + 0.02 and wr.max() <= wr_locked.max() + 0.01


def test_recovery_with_the_shipped_self_collision_rows_ends_at_the_torso(robot, kick):
    # The same lock with the shipped defaults. The swing to the folded branch passes the torso, whose dampers
    # slow it: back under 3 cm after 0.78 s (measured 0.776; 0.97 in session 16, with the band and orientation gain
    # of the time). The arm starts out of the lock before the recovery's window closes (elbow min 7.23 cm in the
    # first 0.1 s; 8.1 with the orientations at gain 30). There the kick's elbow target lies within the torso's
    # 1.5 cm safety distance: the dampers hold the forearm at it and the elbow stays up to 1.05 cm off to the
    # window's end (measured max; without the rows < 1 cm).
    t0 = kick[0].hdr.stamp
    frames = [f for f in kick if f.hdr.stamp - t0 >= LOCK_T]
    core = SolverCore(robot, SolverConfig())
    core.reset(Q_LOCK)
    t, el, wr = _right_arm_run(robot, frames, core)
    assert core.counts["recoveries"] == 1
    back = t[np.argmax(el < 3.0)]
    assert el[t < 0.1].min() > 7.0 and back <= 0.9, back
    assert el[t >= 1.0].max() < 1.3, el[t >= 1.0].max()
    assert core.collision is not None and core.collision.min_distance >= core.collision.d_s - 1e-3
    assert np.percentile(wr, 99) < 0.25, np.percentile(wr, 99)  # the wrist as in the lock (p99 0.18)


def test_recovery_does_not_fire_on_the_speed_saturated_kicks(robot, kick):
    # The clip's kicks up to 2.4 s (wrist targets at 1-3 m/s, the wrist level often not met, the right elbow 5-20 cm
    # off while the wrist is within 2 cm now and then): no lock, and the recovery stays out.
    t0 = kick[0].hdr.stamp
    frames = [f for f in kick if f.hdr.stamp - t0 <= 2.4]
    core = SolverCore(robot, SolverConfig(recovery=True))
    core.reset(robot.q_rest)
    step_through(core, frames)
    assert core.counts["recoveries"] == 0
    # The trigger without its lock conditions (elbow 5 cm off for 20 ms with the wrist within 2 cm, which was the
    # default) fires there (measured 6 times): what made every vigorous clip's elbow worse.
    loose = SolverCore(robot, SolverConfig(recovery=True))
    loose.recovery = LockupRecovery(
        robot,
        RecoveryConfig(
            trigger_time=0.02, wrist_tolerance=0.02, stop_margin=np.inf, min_progress=np.inf, met_fraction=0
        ),
    )
    loose.reset(robot.q_rest)
    step_through(loose, frames)
    assert loose.recovery.events >= 1


def test_recovery_takes_the_arm_out_of_the_lock_that_follows_the_kicks(robot, kick):
    # From rest with the shipped limits (arms 8 rad/s, waist 3) and the strict hierarchy on every tick, the right arm
    # locks after the kicks: without the recovery its elbow drifts 12 -> 21 cm off between 2.3 and 3.0 s with the
    # wrist met (measured 20.7 cm mean over 2.8-3.0 s). The recovery fires there (2.57 s) and has it at 5.1 cm by
    # then, the wrist as close (0.18 cm). (The shipped saturation trade keeps this arm out of that lock: 9.7 cm over
    # 2.8-3.0 s, no recovery either way; and so does the shipped centring band, 0.15: 1.04 cm without the recovery
    # (the braking dampers, off by default, alone: 0.48). The lock is what this test needs: the solver of the time,
    # strict, band 0.25, orientations at gain 30.)
    t0 = kick[0].hdr.stamp
    frames = [f for f in kick if f.hdr.stamp - t0 <= 3.0]
    out = {}
    for recovery in (False, True):
        core = SolverCore(robot, SolverConfig(recovery=recovery, saturation_weight=0.0, **OF_THE_TIME))
        core.reset(robot.q_rest)
        t, el, wr = _right_arm_run(robot, frames, core)
        end = t >= 2.8
        out[recovery] = (el[end].mean(), wr[end].mean(), core.counts["recoveries"])
    assert out[False][0] > 15.0 and out[False][2] == 0, out
    assert out[True][2] >= 1 and out[True][0] < 0.5 * out[False][0], out
    assert out[True][1] < out[False][1] + 0.05, out
