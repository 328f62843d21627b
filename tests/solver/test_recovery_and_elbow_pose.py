"""No lock-up on the real wave-left-hand clip (range centring shipped, recovery opt-in); the paper's elbow pose."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.evaluation.runner import run_algorithm
from services.solver.core import SolverConfig, SolverCore
from shared.messages import Header, Target, TaskTargets
from shared.robot.pinocchio_model import build_robot_model
from shared.robot.profile import load_profile
from shared.rotations import matrix_to_quat
from shared.targets import ELBOWS, TARGET_NAMES
from tests.support.lockstep import clip_targets_until
from tests.support.profiles import g1_with_the_hand_as_wrist_point

DT = 0.002
#: The clip and the window of the known lock-up (issue 12: left shoulder roll and yaw at their stops at ~7 s).
WAVE = "dataset-2_wave-left-hand_masculine_001.bvh"
UNTIL = 7.6  # [s] of clip: past the lock-up, not the whole clip (the test's cost)


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def _longest(bad: np.ndarray, dt: float) -> float:
    best = cur = 0
    for b in bad:
        cur = cur + 1 if b else 0
        best = max(best, cur)
    return best * dt


def _wave_runs(robot, variants: dict[str, dict]) -> dict[str, tuple[float, float, float, int]]:
    """variant -> (longest run [s] of the left elbow > 10 cm off, its max [cm], left wrist p99 [cm], recoveries)."""
    targets = clip_targets_until(WAVE, robot, UNTIL)
    out = {}
    for name, solver in variants.items():
        tr = run_algorithm(robot, targets, "hqp-nullspace", qp="daqp", sim=False, solver=solver, collisions=False)
        el = 100 * np.linalg.norm(tr.ref_p["left_elbow"] - tr.kin_p["left_elbow"], axis=1)
        wr = 100 * np.linalg.norm(tr.ref_p["left_wrist"] - tr.kin_p["left_wrist"], axis=1)
        out[name] = (
            _longest(el > 10.0, DT),
            float(np.nanmax(el)),
            float(np.nanpercentile(wr, 99)),
            tr.counts["recoveries"],
        )
    return out


def test_wave_left_hand_has_no_lock_up_with_the_shipped_defaults(robot, tmp_path):
    assert SolverConfig().range_centring_cost > 0 and SolverConfig().recovery  # what ships
    # The shipped G1 (wrist point on the pitch axis): no lock, even without the centring (measured max 3.7 cm,
    # 2.8 without it). The lock below was found with the wrist point on the hand link (4.6 cm further out, before
    # session 15): the centring and the recovery are checked on that profile, where the lock is known.
    shipped = _wave_runs(robot, {"shipped": {}})["shipped"]
    assert shipped[0] == 0.0, shipped
    # There the wrist orientations run as they did then (gain 30, cost 0.3): with session 18's (200, 0.045) the arm
    # does not lock even without the centring (max 3.1 cm).
    hand = build_robot_model(load_profile(g1_with_the_hand_as_wrist_point(tmp_path)))
    then = {"orientation_gain": 30.0, "wrist_orientation_cost": 0.3}
    out = _wave_runs(
        hand,
        {
            "shipped": then,
            "no_centring": {**then, "range_centring_cost": 0.0, "recovery": False},
            "recovery_only": {**then, "range_centring_cost": 0.0},
        },
    )
    # Without the joint-range centring the elbow sits ~25 cm off for more than 0.3 s (the lock-up the
    # issue reports: shoulder roll and yaw and the waist pitch drifted into their stops; measured 0.35 s and
    # 25.0 cm with the G1's limits, arms 8 rad/s and waist 3, over 0.4 s and 29.7 cm at the 4 rad/s of session 12)
    # ...
    assert out["no_centring"][0] > 0.3 and out["no_centring"][1] > 22.0, out
    # ... with the shipped defaults it never leaves 10 cm (measured max 4.4 cm), and the wrists (level 1)
    # are no worse.
    assert out["shipped"][0] == 0.0, out
    assert out["shipped"][1] < 0.25 * out["no_centring"][1], out
    assert out["shipped"][2] <= out["no_centring"][2] + 0.1, out
    # The recovery alone fires once, in the lock (not on the start-up transient, where its earlier trigger
    # fired and sent the arm elsewhere): the arm has to swing round to the other branch, so the elbow is still more
    # than 10 cm off for about 0.5 s (measured 0.55 against 0.59 s, max 26 against 29 cm); the wrists no worse.
    # The kick_normal lock, which the centring does not prevent, is in test_lockup_recovery.py.
    assert out["recovery_only"][3] == 1, out
    assert out["recovery_only"][0] < out["no_centring"][0] and out["recovery_only"][1] < out["no_centring"][1], out
    assert out["recovery_only"][2] <= out["no_centring"][2] + 0.1, out


def _targets(robot, q, q_elbow_R, use_rotation, seq, t):
    poses = robot.frame_poses(q)
    rot = robot.frame_poses(q_elbow_R)
    out = {}
    for n in TARGET_NAMES:
        p, R = poses[n]
        R = rot[n][1] if n in ELBOWS else R
        out[n] = Target(p, matrix_to_quat(R), np.zeros(3), np.zeros(3), True, use_rotation or n not in ELBOWS)
    return TaskTargets(Header(seq, t), out)


def _elbow_rotation_error(robot, q, q_elbow_R) -> float:
    got, want = robot.frame_poses(q), robot.frame_poses(q_elbow_R)
    return max(float(np.degrees(np.linalg.norm(pin.log3(want[n][1].T @ got[n][1])))) for n in ELBOWS)


def test_elbow_orientations_are_tracked_on_level_2_when_asked(robot):
    # Positions from one posture, elbow orientations from a nearby one: only the elbow orientation rows
    # (on with use_rotation) pull the elbows' twist towards them.
    rng = np.random.default_rng(8)
    q0 = robot.q_rest + np.r_[np.zeros(3), rng.uniform(-0.3, 0.3, robot.nq - 3)]
    q_rot = q0 + np.r_[np.zeros(3), rng.uniform(-0.25, 0.25, robot.nq - 3)]
    errors = {}
    for flag in (False, True):
        core = SolverCore(robot, SolverConfig(qp="daqp", self_collision=False))
        core.reset(q0)
        for k in range(400):
            cmd = core.step(_targets(robot, q0, q_rot, flag, k, k * DT), None, k * DT)
        errors[flag] = _elbow_rotation_error(robot, cmd.q, q_rot)
        assert any(t in core.levels[1] for t in core.elbow_orientation_tasks) == flag
        # level 1 (wrist positions) is untouched by the elbow orientation rows
        assert cmd.residuals[0] < 1e-3
    assert errors[True] < 0.7 * errors[False], errors  # measured 14.4 vs 25.2 deg: the rows trade against the others
