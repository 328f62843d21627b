"""The eval's reachability check is collision-aware: a wrist target that puts the robot hand inside its own trunk
is not reachable, however well the (collision-blind) IK reaches it (``services/evaluation/reachability.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from services.evaluation.reachability import IK_TOL, check_targets, trunk_for
from shared.messages import Header, Target, TaskTargets
from shared.rotations import matrix_to_quat
from tests.retarget.conftest import torso_front


def _stream(robot, lefts, R):
    """One frame per left wrist target (orientation R), the other targets at the rest pose."""
    poses = robot.frame_poses(robot.q_rest)
    out = []
    for k, left in enumerate(lefts):
        tt = {}
        for n, (p, Rn) in poses.items():
            p, Rn = (left, R) if n == "left_wrist" else (p, Rn)
            tt[n] = Target(np.asarray(p, float), matrix_to_quat(Rn), np.zeros(3), np.zeros(3), True, True)
        out.append(TaskTargets(Header(k, 0.01 * k), tt))
    return out


def test_a_target_inside_the_torso_is_not_reachable_and_one_just_outside_is(robot14):
    trunk = trunk_for(robot14)
    rest = robot14.frame_poses(robot14.q_rest, names=("left_wrist", "left_elbow"))
    R, elbow = rest["left_wrist"][1], rest["left_elbow"][0]  # the stream's elbow target: the rest pose's
    inside, outside = (torso_front(trunk, R, depth, elbow)[0] for depth in (0.03, -0.003))  # 3 cm in, 3 mm out
    rep = check_targets(robot14, _stream(robot14, [inside, outside], R))
    assert (rep.wrist_res["left"] <= IK_TOL).all()  # the IK alone reaches both
    assert rep.body_dist["left"][0] == pytest.approx(-0.03, abs=1e-3)
    assert rep.body_dist["left"][1] == pytest.approx(0.003, abs=1e-3)
    assert rep.reachable()["left"].tolist() == [False, True]
    assert not rep.reachable(pair=True)["left"][0]
    assert rep.fraction() == pytest.approx(3 / 4)  # 4 wrist targets, the one in the body out
    counts = rep.in_body()
    assert counts["frames_inside"] == 1
    assert counts["frames_within_safety"] == 2  # 3 mm out is within the solver's 1.5 cm
    assert counts["min_distance_cm"] == pytest.approx(-3.0, abs=0.1)


def test_the_body_check_can_be_left_out(robot14):
    R = robot14.frame_poses(robot14.q_rest, names=("left_wrist",))["left_wrist"][1]
    inside = torso_front(trunk_for(robot14), R, 0.03)[0]
    rep = check_targets(robot14, _stream(robot14, [inside], R), body=False)
    assert rep.reachable()["left"].tolist() == [True]
    assert rep.in_body()["frames_inside"] is None
