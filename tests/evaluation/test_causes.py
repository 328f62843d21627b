"""Why a fidelity goal is missed (``services/evaluation/causes.py``): known answers on a hand-made trace."""

from __future__ import annotations

import numpy as np
import pytest

from services.evaluation.causes import CAUSES, FRAME_STEP_TICKS, NONE, explain_misses, miss_causes
from services.evaluation.goals import clip_goals, goals_lines, goals_summary
from services.evaluation.reachability import ReachabilityReport
from services.solver.core import HOLD_ACCELERATION, HOLD_SPEED, HOLD_STOP
from shared.mirror import arm_joints
from shared.robot.pinocchio_model import build_robot_model
from tests.evaluation.test_metrics import K, synthetic_trace
from tests.support.goal_metrics import hqp_meeting_every_goal

FRAME = 16  # ticks per frame of the synthetic trace (its seq is tick // 16)


@pytest.fixture(scope="module")
def robot():
    return build_robot_model()


def _trace(robot, off_m: float = 0.02):
    """The left wrist ``off_m`` off on ticks 40-49, exact elsewhere. On those ticks: a left arm joint at its speed
    cap (40-44), the left arm held by a collision damper (45-46), tick 47 held by nothing, a frame arriving on 48;
    the waist at its acceleration band throughout (it carries both arms: neither arm's cause); the right arm at a
    stop on 100-109, its wrist exact there."""
    tr = synthetic_trace(robot, {})
    tr.kin_p["left_wrist"][40:50] += np.array([0.0, off_m, 0.0])
    left, right = arm_joints(robot, "left"), arm_joints(robot, "right")
    waist = robot.indices(robot.profile.waist)
    tr.holds = np.zeros((K, robot.nq), dtype=np.int8)
    tr.collision_held = np.zeros((K, robot.nq), dtype=bool)
    tr.holds[40:45, left[0]] = HOLD_SPEED
    tr.collision_held[45:47, left[2]] = True
    tr.holds[:, waist] = HOLD_ACCELERATION
    tr.holds[100:110, right[3]] = HOLD_STOP
    tr.frame_tick = np.arange(0, K, FRAME)
    return tr


def test_the_ticks_over_the_bar_and_what_held_them(robot):
    c = miss_causes(_trace(robot), robot, None, "wrist_cm", 1.0)
    assert (c["ticks_over"], c["ticks_scored"]) == (10, 2 * K)
    assert set(c["shares"]) == {"self_collision", "speed_cap", "joint_stop", "acceleration", "frame_step", NONE}
    assert c["shares"] == pytest.approx(
        {"self_collision": 0.2, "speed_cap": 0.5, "joint_stop": 0.0, "acceleration": 0.0, "frame_step": 0.2, NONE: 0.1}
    )  # 48 and 49 are the step of the frame arriving on 48; the waist's band and the right arm's stop count for none
    steps = 2 * FRAME_STEP_TICKS * len(range(0, K, FRAME))  # both arms, the first ticks of each frame
    assert c["base"]["frame_step"] == pytest.approx(steps / (2 * K))
    assert c["base"]["joint_stop"] == pytest.approx(10 / (2 * K))  # the right arm's ticks at its stop
    assert c["main"] == "speed_cap"  # 50 % against 1 %: further above its base than the collision's 20 % vs 0.5 %
    assert miss_causes(_trace(robot), robot, None, "wrist_cm", 2.5)["ticks_over"] == 0  # 2 cm is within 2.5
    # every tick over the bar: no flag is above its base, and the main cause is one the misses have, never a 0 %
    everywhere = miss_causes(_trace(robot), robot, None, "wrist_cm", -1.0)
    assert everywhere["shares"] == pytest.approx(everywhere["base"])
    assert everywhere["shares"][everywhere["main"]] > 0


def test_behind_a_peer_the_excess_is_what_is_explained(robot):
    """Against a peer the ticks are weighed by how far the judged error is above the peer's: a peer as far off on
    45-49 and exact on 40-44 leaves only the speed-capped ticks 40-44 behind it; one 1 cm off on all of 40-49 halves
    each tick's excess and the shares are the over-bar ones."""
    ours = _trace(robot)
    peer = synthetic_trace(robot, {})
    peer.algo = "wqp"
    peer.kin_p["left_wrist"][45:50] += np.array([0.0, 0.02, 0.0])
    c = miss_causes(ours, robot, None, "wrist_cm", 0.0, peer)
    assert c["weighed_by"] == "excess over wqp's error" and c["ticks_over"] == 5
    assert c["shares"]["speed_cap"] == pytest.approx(1.0) and c["main"] == "speed_cap"
    half = synthetic_trace(robot, {})
    half.kin_p["left_wrist"][40:50] += np.array([0.0, 0.01, 0.0])
    c = miss_causes(ours, robot, None, "wrist_cm", 0.0, half)
    assert c["ticks_over"] == 10 and c["shares"] == pytest.approx(
        miss_causes(ours, robot, None, "wrist_cm", 1.0)["shares"]
    )
    assert miss_causes(ours, robot, None, "wrist_cm", 0.0, ours)["main"] is None  # never behind itself


def test_target_causes_from_the_ik_check(robot):
    """Frame 2 (ticks 32-47) of the left arm is out of reach and too fast for the joints, frame 3 (48-63) inside
    the body: those name 8 and 2 of the 10 ticks over the bar; a frame within the safety distance of the body and
    outside it (frame 5) is at the body too, not out of reach. With the IK check the stuck ticks are those on
    reachable targets only, so none here."""
    frames = K // FRAME + 1
    res = {s: np.zeros(frames) for s in ("left", "right")}
    res["left"][2] = 0.05
    body = {s: np.full(frames, 0.1) for s in ("left", "right")}
    body["left"][3] = -0.01
    body["left"][5] = 0.01  # within the 1.5 cm safety distance
    speed = {s: np.full(frames, 1.0) for s in ("left", "right")}
    speed["left"][2] = 50.0
    report = ReachabilityReport(np.arange(frames), res, res, speed, vmax=8.0, body_dist=body, safety_distance=0.015)
    tr = _trace(robot, off_m=0.03)
    c = miss_causes(tr, robot, report, "wrist_cm", 1.0)
    assert set(c["shares"]) == {*CAUSES, NONE}
    assert c["shares"]["target_unreachable"] == pytest.approx(0.8)
    assert c["shares"]["target_too_fast"] == pytest.approx(0.8)
    assert c["shares"]["target_at_body"] == pytest.approx(0.2)
    assert c["base"]["target_at_body"] == pytest.approx(2 * FRAME / (2 * K))  # frames 3 and 5 of the left arm
    assert c["base"]["target_unreachable"] == pytest.approx(FRAME / (2 * K))  # frame 2 only
    assert c["main"] == "target_unreachable"  # the first of the two furthest above their base (80 % vs 4 %)
    stuck = miss_causes(tr, robot, report, "stuck", 0.1)
    assert stuck["ticks_over"] == 0 and stuck["main"] is None
    assert miss_causes(tr, robot, None, "stuck", 0.1)["ticks_over"] == 10  # without the check every target counts


def test_missed_goals_carry_their_causes_into_the_summary_and_the_log(robot):
    """Only the missed goals with a per-tick figure are explained; the summary keeps each clip's main cause and the
    log line names it with its share."""
    algos = {"hqp-nullspace": hqp_meeting_every_goal(stuck_s=0.3, min_clearance_cm=0.5)}
    goals = clip_goals(algos, {"wrist_p99_cm": 1.0, "wrist_mean_cm": 0.5})
    goals["unmet"].insert(0, "wrist_p99_cm")  # as if the wrist p99 were over its bar too
    goals["checks"]["wrist_p99_cm"]["met"] = False
    explain_misses(goals, {"hqp-nullspace": _trace(robot, off_m=0.015)}, robot, None)
    assert goals["checks"]["wrist_p99_cm"]["causes"]["main"] == "speed_cap"
    assert goals["checks"]["stuck_s"]["causes"]["ticks_over"] == 0  # 1.5 cm is within STUCK_ERR
    assert "causes" not in goals["checks"]["min_clearance_cm"]  # a goal on a count: nothing per tick
    s = goals_summary({"clip_a": goals})
    main = {"cause": "speed_cap", "share": 0.5, "base": 5 / (2 * K)}
    assert s["goals"]["wrist_p99_cm"]["main_causes"] == {"clip_a": pytest.approx(main)}
    assert "main_causes" not in s["goals"]["stuck_s"] and "main_causes" not in s["goals"]["min_clearance_cm"]
    lines = goals_lines(s)
    assert "  wrist_p99_cm: met on 0 of 1; not on clip_a [speed_cap 50 % vs 1 %]" in lines
    assert "  min_clearance_cm: met on 0 of 1; not on clip_a" in lines
