"""``target_adjustment``: how far consistent targets moved from the plain ones, with known answers."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from services.evaluation.metrics import target_adjustment
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
