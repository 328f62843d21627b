"""``target_adjustment``: how far consistent targets moved from the plain ones, with known answers."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.evaluation.metrics import operator_errors, target_adjustment
from shared.messages import Header, Target, TaskTargets
from shared.rotations import matrix_to_quat
from shared.targets import TARGET_NAMES


def _frame(seq: int, elbow_dx: float, turn_deg: float, valid: bool = True) -> TaskTargets:
    R = pin.exp3(np.radians(turn_deg) * np.array([0.0, 0.0, 1.0]))
    tg = {}
    for name in TARGET_NAMES:
        p = np.array([0.3, 0.2, 0.1]) + (np.array([elbow_dx, 0.0, 0.0]) if name.endswith("elbow") else 0.0)
        q = matrix_to_quat(R if name.endswith("wrist") else np.eye(3))
        tg[name] = Target(p, q, np.zeros(3), np.zeros(3), valid or name.endswith("wrist"), name.endswith("wrist"))
    return TaskTargets(Header(seq, 0.01 * seq, 0), tg)


def test_adjustment_is_the_elbow_distance_and_the_hand_angle_per_arm_frame():
    plain = [_frame(k, 0.0, 0.0) for k in range(4)]
    # frames 0-2 moved (elbow 1, 2, 3 cm; hand 10, 20, 30 deg), frame 3 has no valid elbow: not counted
    moved = [_frame(k, 0.01 * (k + 1), 10.0 * (k + 1)) for k in range(3)] + [_frame(3, 0.5, 90.0, valid=False)]
    adj = target_adjustment(plain, moved)
    assert adj["arm_frames"] == 6  # 3 frames x 2 arms
    assert adj["elbow_cm"]["mean"] == pytest.approx(2.0) and adj["elbow_cm"]["max"] == pytest.approx(3.0)
    assert adj["wrist_rot_deg"]["mean"] == pytest.approx(20.0) and adj["wrist_rot_deg"]["max"] == pytest.approx(30.0)
    # identical streams: nothing moved
    same = target_adjustment(plain, plain)
    assert same["elbow_cm"]["max"] == 0.0 and same["wrist_rot_deg"]["max"] == pytest.approx(0.0, abs=1e-6)


def test_operator_errors_score_the_robot_against_the_plain_targets_frame_by_frame(robot17):
    from tests.evaluation.test_metrics import synthetic_trace

    tr = synthetic_trace(robot17, {})
    ticks = np.array([0, 5, 9, 13])  # tick 0: the frame arrived before any command was scored, not counted
    tr.frame_tick, tr.frame_seq = ticks, np.arange(len(ticks)) + 7
    plain = []
    for seq, tick in zip(tr.frame_seq, ticks, strict=True):
        tg = {}
        for n in TARGET_NAMES:
            # the operator's elbow 4 cm from where the robot's is; the hand turned 12 deg from the robot's
            p = tr.kin_p[n][tick - 1] + (np.array([0.0, 0.04, 0.0]) if n.endswith("elbow") else 0.0)
            R = (
                tr.kin_R[n][tick - 1] @ pin.exp3(np.radians(12.0) * np.array([1.0, 0.0, 0.0]))
                if n in tr.kin_R
                else None
            )
            q = matrix_to_quat(R) if R is not None else np.array([1.0, 0.0, 0.0, 0.0])
            tg[n] = Target(p, q, np.zeros(3), np.zeros(3), True, n.endswith("wrist"))
        plain.append(TaskTargets(Header(int(seq), 0.0, 0), tg))
    m = operator_errors(tr, plain)
    assert m["elbow_err_cm_vs_operator"]["mean"] == pytest.approx(4.0) and m["elbow_err_cm_vs_operator"][
        "max"
    ] == pytest.approx(4.0)
    assert m["wrist_err_cm_vs_operator"]["max"] == pytest.approx(0.0, abs=1e-12)
    assert m["wrist_rot_err_deg_vs_operator"]["mean"] == pytest.approx(12.0)
    # 3 frames x 2 arms scored (the frame on tick 0 and a seq the plain stream lacks are skipped)
    tr.frame_seq[1] = 99
    assert operator_errors(tr, plain)["elbow_err_cm_vs_operator"]["mean"] == pytest.approx(4.0)
