"""Wrist targets kept off the robot's trunk (``RetargetConfig.trunk_clearance``, ``services/retarget/trunk.py``)."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from conftest import targets_without_and_with, torso_front

from services.evaluation.runner import clip_targets
from services.ingest import load_clip
from services.retarget.retargeter import RetargetConfig, Retargeter
from services.retarget.trunk import FAST, FAST_CLEARANCE, SLOW, HandChain, HandSpeed, TrunkClearance
from shared.rotations import quat_to_matrix

#: Distance tolerance [m] of the pushed hand against the clearance (the Newton steps stop within 0.2 mm).
TOL = 5e-4


@pytest.fixture(scope="module")
def trunk(robot14):
    return TrunkClearance(robot14, {s: robot14.profile.frames[f"{s}_wrist"] for s in ("left", "right")})


@pytest.fixture(scope="module")
def hand_trunk(robot14):
    """As the retargeter builds it: the wrist link and the hand link past it (the G1's pitch and yaw links)."""
    prof = robot14.profile
    return TrunkClearance(
        robot14,
        {s: prof.frames[f"{s}_wrist"] for s in ("left", "right")},
        hand_frames={s: prof.orientation_frame(f"{s}_wrist") for s in ("left", "right")},
    )


@pytest.fixture(scope="module")
def hand_down(robot14):
    """The left wrist target's orientation at the rest pose (3, 3): the hand hanging, pointing forward-down."""
    return robot14.frame_poses(robot14.q_rest, names=("left_wrist",))["left_wrist"][1]


def test_a_target_inside_the_trunk_maps_to_the_surface_along_the_normal(trunk, hand_down):
    """The hand 3 cm inside the torso's front: published at the clearance, moved along the front's normal."""
    p, normal = torso_front(trunk, hand_down, depth=0.03)
    assert trunk.nearest("left", p, hand_down)[0] < -0.02
    out = trunk("left", p, hand_down)
    assert abs(trunk.nearest("left", out, hand_down)[0] - trunk.clearance) < TOL
    move = out - p
    assert np.linalg.norm(move) == pytest.approx(0.03 + trunk.clearance, abs=2e-3)
    assert move @ normal / np.linalg.norm(move) > 0.99


def test_a_target_clear_of_the_trunk_is_unchanged(trunk, hand_down):
    p, _ = torso_front(trunk, hand_down, depth=-0.05)
    assert trunk("left", p, hand_down) is p


def test_a_target_sliding_into_the_trunk_does_not_jump(trunk, hand_down):
    """From 5 cm outside to 8 cm inside in 1 mm steps: the published target moves by at most the step."""
    p0, normal = torso_front(trunk, hand_down, depth=-0.05)
    slide = np.array([0.0, 0.3, -1.0])  # diagonally in, along the front and down
    slide -= (slide @ normal) * normal
    slide /= np.linalg.norm(slide)
    outs = []
    for k in range(131):
        p = p0 - normal * (0.001 * k) + slide * (0.0003 * k)
        outs.append(trunk("left", p, hand_down))
    steps = np.linalg.norm(np.diff(outs, axis=0), axis=1)
    assert steps.max() < 0.0015
    for o in outs:
        assert trunk.nearest("left", o, hand_down)[0] > trunk.clearance - TOL


def test_a_target_in_front_of_the_chest_leaves_forward_and_slides_across_it(trunk, hand_down):
    """A hand 2 cm inside the chest's front, at the G1 chest logo's height, slid across the chest in 2 mm steps:
    every push points out of the front and the published target never jumps. The logo is a small link on the
    torso; from its own longest axis (in its plane) the hand was pushed sideways across the chest, 3.5 cm at
    once where the torso became the nearer link (kick_normal's right hand, before the exit rays came from the
    torso's body as a whole)."""
    mujoco.mj_kinematics(trunk.model, trunk.data)
    z = trunk.data.geom_xpos[trunk.model.geom("polytope:logo_link").id][2]
    p = np.array([0.4, 0.0, z])
    while trunk.nearest("left", p, hand_down)[0] > 0.0:  # walk in until the hand touches the chest
        p[0] -= 0.002
    outs = []
    for y in np.arange(-0.08, 0.0801, 0.002):
        q = np.array([p[0] - 0.02, y, z])
        out = trunk("left", q, hand_down)
        move = out - q
        assert move[0] / np.linalg.norm(move) > 0.7, (y, move)  # out of the front (the front curves round at +-8 cm)
        assert abs(trunk.nearest("left", out, hand_down)[0] - trunk.clearance) < TOL
        outs.append(out)
    assert np.linalg.norm(np.diff(outs, axis=0), axis=1).max() < 0.004


def test_the_hand_chain_poses_the_wrist_link_from_the_forearm(robot14):
    """The wrist target gives the wrist (pitch) link's origin and the hand (yaw) link's orientation; with the forearm's
    roll axis the pitch link's orientation and the hand link's origin follow exactly (the sine of the pitch is the
    forearm's share along the yaw axis). Without the forearm the joint is taken at 0: off by the yaw angle."""
    m, d = robot14.model, robot14.model.createData()
    ids = [m.getFrameId(f"left_{n}") for n in ("wrist_roll_link", "wrist_pitch_link", "wrist_yaw_link")]
    chain = HandChain(robot14, "left_wrist_pitch_link", "left_wrist_yaw_link")
    rng = np.random.default_rng(0)
    guess = []
    for _ in range(50):
        q = rng.uniform(robot14.lower, robot14.upper)
        pin.framesForwardKinematics(m, d, q)
        roll, wrist, hand = (d.oMf[i] for i in ids)
        R_wrist, p_hand = chain.pose(wrist.translation, hand.rotation, roll.rotation[:, 0])
        assert np.allclose(R_wrist, wrist.rotation, atol=1e-9) and np.allclose(p_hand, hand.translation, atol=1e-9)
        guess.append(np.linalg.norm(chain.pose(wrist.translation, hand.rotation, None)[1] - hand.translation))
    assert np.median(guess) > 0.02  # the yaw angle's turn of the 4.6 cm lever


def test_a_hand_turned_into_the_torso_is_pushed_out_though_its_wrist_link_is_clear(trunk, hand_trunk, hand_down):
    """The forearm and hand pointing straight at the belly, the wrist link 5 mm beyond the clearance: the wrist link
    alone is clear (the target stays), the hand link 4.6 cm further in is not, and the hand chain pushes the target
    out along the front's normal until the whole hand keeps the clearance."""
    p0, normal = torso_front(trunk, hand_down, depth=-0.05)
    x = -normal  # forearm, wrist link and hand all pointing into the torso (every wrist joint at 0)
    z = np.array([0.0, 0.0, 1.0]) - x[2] * x
    z /= np.linalg.norm(z)
    R = np.column_stack([x, np.cross(z, x), z])
    p = p0 + 0.15 * normal  # everything clear
    while trunk.nearest("left", p, R)[0] > trunk.clearance + 0.005:  # walk in: the wrist link 5 mm beyond it
        p = p - 0.001 * normal
    assert trunk("left", p, R) is p
    assert hand_trunk.nearest("left", p, R, x)[0] < trunk.clearance - 0.01  # measured: 1.6 cm nearer
    out = hand_trunk("left", p, R, forearm=x)
    assert abs(hand_trunk.nearest("left", out, R, x)[0] - hand_trunk.clearance) < TOL
    move = out - p
    assert np.linalg.norm(move) > 0.01 and move @ normal / np.linalg.norm(move) > 0.99


def test_real_clip_hands_stay_off_the_trunk(bvh_clips, robot14, workspace, hand_trunk):
    """call_normal_001: the operator's left hand rests on the belly, and its plain wrist targets put the robot
    hand inside the trunk (at the waist's rest); with trunk_clearance every published hand keeps the clearance,
    the targets move continuously, and the velocities are differences of the published positions."""
    out = targets_without_and_with(bvh_clips, "call_normal_001", workspace, robot14, "trunk_clearance")

    trunk = hand_trunk

    def clearance(targets, side):
        wrists, elbows = ([tt.targets[f"{side}_{n}"] for tt in targets] for n in ("wrist", "elbow"))
        return np.array(
            [trunk.nearest(side, w.p, quat_to_matrix(w.q), np.subtract(w.p, e.p))[0] for w, e in zip(wrists, elbows)]
        )

    assert clearance(out[False], "left").min() < 0.0
    for side in ("left", "right"):
        # the default keeps the fast clearance for a moving hand, the full one for a resting hand
        assert clearance(out[True], side).min() > FAST_CLEARANCE - TOL
        plain = np.array([tt.targets[f"{side}_wrist"].p for tt in out[False]])
        pushed = np.array([tt.targets[f"{side}_wrist"].p for tt in out[True]])
        # no step of the published wrist beyond the operator's own largest one
        assert (
            np.linalg.norm(np.diff(pushed, axis=0), axis=1).max()
            <= np.linalg.norm(np.diff(plain, axis=0), axis=1).max() * 1.05
        )
        # the elbow is placed again where its wrist moved; elsewhere it moves only as far as the next frame's
        # swivel prior (the last placement's direction) carries the difference
        moved = np.linalg.norm(pushed - plain, axis=1) > 0
        # the hands rest on the belly on most of those frames: there the full clearance
        assert abs(np.median(clearance(out[True], side)[moved]) - trunk.clearance) < TOL
        elbows = [np.array([tt.targets[f"{side}_elbow"].p for tt in out[on]]) for on in (False, True)]
        emove = np.linalg.norm(elbows[1] - elbows[0], axis=1)
        assert moved.any() and (emove[moved] > 0).all() and emove[~moved].max() < 0.002  # measured 0.65 mm


@pytest.fixture(scope="module")
def fast(robot14):
    return TrunkClearance(
        robot14, {s: robot14.profile.frames[f"{s}_wrist"] for s in ("left", "right")}, fast_clearance=0.003
    )


def test_a_fast_hand_keeps_the_fast_clearance(trunk, fast, hand_down):
    """Full clearance up to SLOW, the fast one from FAST, falling continuously in between (no jump of the target
    as the speed crosses them); a hand 3 cm inside the torso's front is published at the full clearance at rest,
    at the fast one when fast, along the same normal; without ``fast_clearance`` the speed changes nothing."""
    assert fast.clearance_at(0.0) == fast.clearance_at(SLOW) == fast.clearance == trunk.clearance
    assert fast.clearance_at(FAST) == fast.clearance_at(5.0) == fast.fast_clearance == 0.003
    mid = np.array([fast.clearance_at(v) for v in np.linspace(SLOW, FAST, 401)])
    assert (np.diff(mid) < 0).all() and np.abs(np.diff(mid)).max() < 1e-4
    p, normal = torso_front(fast, hand_down, depth=0.03)
    for speed, c in ((0.0, fast.clearance), (2 * FAST, 0.003)):
        out = fast("left", p, hand_down, speed=speed)
        assert abs(fast.nearest("left", out, hand_down)[0] - c) < TOL
        assert (out - p) @ normal / np.linalg.norm(out - p) > 0.99
    assert np.array_equal(trunk("left", p, hand_down, speed=2 * FAST), trunk("left", p, hand_down))


def test_hand_speed_follows_a_steady_motion():
    """1 m/s in 10 ms steps: the low-passed speed rises towards 1 m/s (within 1 % after 5 time constants) and
    restarts from 0 after a reset or a gap (dt None)."""
    hs = HandSpeed(tau=0.1)
    assert hs.update(np.zeros(3), 0.01) == 0.0  # the first sample has nothing to difference against
    speeds = [hs.update(np.array([0.01 * k, 0.0, 0.0]), 0.01) for k in range(1, 51)]
    assert speeds[0] == pytest.approx(1.0 - np.exp(-0.1))
    assert speeds[-1] == pytest.approx(1.0, abs=0.01)
    assert hs.update(np.array([0.6, 0.0, 0.0]), None) == 0.0
    hs.reset()
    assert hs.update(np.ones(3), 0.01) == 0.0


def test_published_velocities_are_those_of_the_pushed_path(bvh_clips, robot14, workspace):
    """call_normal_001 with the push (and no velocity low-pass): each published wrist velocity is the finite
    difference of the published (pushed) positions, not of the operator's plain ones, so the solver's feed-forward
    follows the path it is asked to track."""
    clip = load_clip(next(p for p in bvh_clips if "call_normal_001" in p.name))
    cfg = RetargetConfig(trunk_clearance=True, velocity_tau=0.0)
    out = clip_targets(clip, Retargeter(cfg, workspace=workspace, robot=robot14))
    plain = clip_targets(
        clip, Retargeter(RetargetConfig(trunk_clearance=False, velocity_tau=0.0), workspace=workspace, robot=robot14)
    )
    t = np.array([tt.hdr.stamp for tt in out])
    P = np.array([tt.targets["left_wrist"].p for tt in out])
    V = np.array([tt.targets["left_wrist"].v for tt in out])
    fd = np.diff(P, axis=0) / np.diff(t)[:, None]
    moved = np.linalg.norm(P - np.array([tt.targets["left_wrist"].p for tt in plain]), axis=1) > 1e-4
    assert moved.sum() > 10
    np.testing.assert_allclose(V[1:], fd, atol=1e-9)


def test_a_target_passing_the_torso_axis_turns_round_it_instead_of_jumping(trunk, hand_down):
    """A hand target driven straight through the chest, front to back, in 1 cm steps (kick_normal's right hand went
    across the chest, 10 cm inside the front). On its own each push leaves along the ray from the torso's axis
    through the hand, so as the hand passes the axis the published target jumps from the front to the back (12.9 cm
    in one step). Chained as the retargeter chains them (each push's ray the next one's prior), the ray turns by
    EXIT_TURN a step at most: the target goes round the side (largest step 5.0 cm), always at the clearance."""
    mujoco.mj_kinematics(trunk.model, trunk.data)
    z = trunk.data.geom_xpos[trunk.model.geom("polytope:logo_link").id][2]
    alone, chained, prior = [], [], None
    for x in np.arange(0.15, -0.10, -0.01):
        q = np.array([x, 0.01, z])
        alone.append(trunk("left", q, hand_down))
        out, prior = trunk.push("left", q, hand_down, prior=prior)
        chained.append(out)
    steps = [np.linalg.norm(np.diff(np.array(t), axis=0), axis=1).max() for t in (alone, chained)]
    assert steps[0] > 0.10 and steps[1] < 0.06, steps
    assert min(trunk.nearest("left", o, hand_down)[0] for o in chained) > trunk.clearance - TOL


def test_the_status_counts_the_frames_pushed_and_no_others(bvh_clips, robot14, workspace):
    """``trunk_cleared_<side>`` is the number of frames whose wrist target the push moved (until session 25 it counted
    every frame with a valid wrist: the check compared with a fresh view of the row, never the object pushed)."""
    clip = load_clip(next(p for p in bvh_clips if "call_normal_001" in p.name))
    rt = {
        on: Retargeter(RetargetConfig(trunk_clearance=on), workspace=workspace, robot=robot14) for on in (False, True)
    }
    out = {on: clip_targets(clip, r) for on, r in rt.items()}
    for side in ("left", "right"):
        moved = [
            not np.array_equal(a.targets[f"{side}_wrist"].p, b.targets[f"{side}_wrist"].p)
            for a, b in zip(out[False], out[True], strict=True)
        ]
        assert 0 < sum(moved) < len(moved)
        assert rt[True].counts[f"trunk_cleared_{side}"] == sum(moved)
        assert rt[False].counts[f"trunk_cleared_{side}"] == 0


def test_a_hand_link_more_than_one_joint_past_the_wrist_link_leaves_the_wrist_link_alone(robot14, caplog):
    """Another robot's wrist: a hand frame two joints past the wrist link is refused with a one-line reason, and the
    push poses the wrist link alone (as before session 25) instead of failing."""
    with pytest.raises(ValueError, match="not one revolute joint past"):
        HandChain(robot14, "left_wrist_roll_link", "left_wrist_yaw_link")
    frames = {"left": "left_wrist_roll_link"}
    with caplog.at_level("WARNING"):
        trunk = TrunkClearance(robot14, frames, hand_frames={"left": "left_wrist_yaw_link"})
    assert trunk.chains == {"left": None}
    assert "wrist link alone" in caplog.text
