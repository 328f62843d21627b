"""The swivel action kind: the elbow's angle on the circle of elbows that reach the wrist, and its placement."""

from __future__ import annotations

import numpy as np
import pytest

from services.posture.features import mirror_action
from services.posture.policy import PolicyError, PosturePolicy, save_policy
from services.posture.swivel import SwivelFrame
from shared.robot.pinocchio_model import build_robot_model
from shared.targets import SIDES
from tests.posture.policy_files import random_weights, write_random_policy

#: A G1-like left arm: shoulder centre [m], upper arm and forearm [m] (the measured G1: 0.192 / 0.184).
C, LU, LF = np.array([0.0, 0.136, 0.30]), 0.19, 0.18


@pytest.fixture(scope="module")
def frame():
    return SwivelFrame.for_arm(C, LU, LF, "left")


def random_wrists(rng, n, centre=C, lu=LU, lf=LF):
    """n wrists (n, 3) [m] within reach of an arm of lengths lu, lf [m] (|lu - lf| + 2 cm to lu + lf - 1 cm from the
    shoulder centre)."""
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return centre + u * rng.uniform(abs(lu - lf) + 0.02, lu + lf - 0.01, (n, 1))


def circle_elbow(p, v):
    """An elbow (3,) reaching wrist p, built here from scratch: law of cosines on the shoulder-wrist axis,
    offset along v's component normal to the axis."""
    a = p - C
    d = np.linalg.norm(a)
    u = a / d
    x = (LU**2 - LF**2 + d**2) / (2 * d)
    n = v - (v @ u) * u
    return C + x * u + np.sqrt(LU**2 - x**2) * n / np.linalg.norm(n)


def test_placed_elbow_reaches_the_wrist_and_its_angle_round_trips(frame):
    rng = np.random.default_rng(0)
    for p in random_wrists(rng, 200):
        phi = rng.uniform(-np.pi, np.pi)
        cs = np.array([np.cos(phi), np.sin(phi)])
        e = frame.place(2.5 * cs, p)  # only the direction of the output counts
        assert np.linalg.norm(e - C) == pytest.approx(LU, abs=1e-9)  # on both spheres
        assert np.linalg.norm(e - p) == pytest.approx(LF, abs=1e-9)
        np.testing.assert_allclose(frame.angle(e, p), cs, atol=1e-9)
        # an elbow made independently on the circle: its angle places it back where it was
        e2 = circle_elbow(p, rng.normal(size=3))
        np.testing.assert_allclose(frame.place(frame.angle(e2, p), p), e2, atol=1e-9)


def test_angle_reference_at_the_pole_is_the_lowest_elbow_and_turns_right_handed(frame):
    a0 = np.array(frame.pole)
    p = C + 0.3 * a0  # wrist along the pole
    circle = np.array([frame.place([np.cos(t), np.sin(t)], p) for t in np.linspace(-np.pi, np.pi, 721)])
    lowest = circle[np.argmin(circle[:, 2])]
    np.testing.assert_allclose(frame.place([1.0, 0.0], p), lowest, atol=1e-3)  # 0.5° of grid
    o = frame.place([1.0, 0.0], p) + frame.place([-1.0, 0.0], p)
    quarter = frame.place([0.0, 1.0], p) - o / 2  # phi = 90°: along a0 x e1
    e1 = frame.place([1.0, 0.0], p) - o / 2
    np.testing.assert_allclose(np.cross(a0, e1), quarter, atol=1e-9)


def test_angle_is_continuous_through_arms_straight_down_and_up(frame):
    """A gravity reference is singular at both (where the operators' arms go); this one only behind the back."""
    e = np.array([0.0, 0.3, 0.5]) - C  # an elbow offset that stays off the axis on this path
    prev = None
    # wrist from behind the hip, straight below the shoulder, forward, straight above, to behind the head
    for t in np.linspace(-np.pi / 2 - 0.6, np.pi / 2 + 0.3, 2061):
        p = C + 0.3 * np.array([np.cos(t), 0.0, np.sin(t)])
        cs = frame.angle(C + e, p)
        if prev is not None:
            assert np.linalg.norm(cs - prev) < 0.01  # 0.1° steps of the wrist: no jump
        prev = cs


def test_mirrored_sample_keeps_cos_and_negates_sin():
    right = SwivelFrame.for_arm(C * [1, -1, 1], LU, LF, "right")
    left = SwivelFrame.for_arm(C, LU, LF, "left")
    rng = np.random.default_rng(1)
    M = np.array([1.0, -1.0, 1.0])
    for p in random_wrists(rng, 50):
        e = circle_elbow(p, rng.normal(size=3))
        np.testing.assert_allclose(
            right.angle(e * M, p * M), mirror_action(left.angle(e, p), np.ones(7), "swivel"), atol=1e-9
        )


@pytest.fixture(scope="module")
def robot14():
    return build_robot_model(with_waist=False)


def test_swivel_policy_gives_elbows_that_reach_its_wrists(tmp_path, robot14):
    cs = {"left": [0.6, 0.8], "right": [-1.2, 0.5]}
    pol = PosturePolicy.load(write_random_policy(tmp_path / "s.npz", robot14, swivel=cs))
    assert pol.kind == "swivel" and pol.gives_elbow
    rng = np.random.default_rng(2)
    for _ in range(50):
        S = np.zeros((2, 14))
        S[:, 0] = 1.0
        for i in range(2):
            f = pol.swivel[i]
            S[i, 4:7] = random_wrists(rng, 1, f.centre, f.upper, f.fore)[0]  # the robot arm's own reach
        out, ref = pol.act(S), pol.act_reference(S)
        for i, s in enumerate(SIDES):
            f = pol.swivel[i]
            for e in (out.elbow[i], ref.elbow[i]):
                assert np.linalg.norm(e - f.centre) == pytest.approx(f.upper, abs=1e-6)
                assert np.linalg.norm(e - S[i, 4:7]) == pytest.approx(f.fore, abs=1e-6)
                np.testing.assert_allclose(f.angle(e, S[i, 4:7]), np.array(cs[s]) / np.linalg.norm(cs[s]), atol=1e-6)


def test_swivel_file_without_its_angle_frames_is_refused(tmp_path, robot14):
    path = write_random_policy(tmp_path / "s.npz", robot14, swivel={})
    pol = PosturePolicy.load(path)
    meta = dict(pol.meta)
    meta["arms"] = {s: {k: v for k, v in a.items() if k != "swivel"} for s, a in meta["arms"].items()}
    w = random_weights(np.random.default_rng(0), action=2)
    save_policy(tmp_path / "bare.npz", w, meta)
    with pytest.raises(PolicyError, match="angle frames"):
        PosturePolicy.load(tmp_path / "bare.npz")
    save_policy(tmp_path / "three.npz", random_weights(np.random.default_rng(0)), pol.meta)  # a 3-output encoder
    with pytest.raises(PolicyError, match="expected 14 -> 2"):
        PosturePolicy.load(tmp_path / "three.npz")
