"""The balance layer on its own: leg IK, the pendulum LQR, and the robot standing and recovering from a push."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from services.wbc.balance import BalanceController, Reference, leg_ik, wip_feedforward, wip_lqr, yaw_pitch_roll
from services.wbc.runner import measured_q, place_robot
from shared.robot.wheeled import build_wheeled_robot


def test_leg_ik_places_the_wheel_where_asked():
    rng = np.random.default_rng(0)
    for _ in range(50):
        dx, dz = rng.uniform(-0.05, 0.05), rng.uniform(-0.367, -0.207)  # the profile's z_range
        hp, kn = leg_ik(dx, dz, 0.2)
        x = -0.2 * (math.sin(hp) + math.sin(hp + kn))
        z = -0.2 * (math.cos(hp) + math.cos(hp + kn))
        assert (x, z) == pytest.approx((dx, dz), abs=1e-12)
        assert -2.7 <= kn <= -0.69  # Table 2's knee range for these heights


def test_lqr_stabilises_the_linear_pendulum():
    M, h, I, m_w, I_w, r, dt = 25.0, 0.31, 0.6, 3.0, 0.013, 0.0927, 0.001
    K = wip_lqr(M, h, I, m_w, I_w, r, dt, (1e4, 2e3, 500.0, 10.0), 1.0)
    assert K.shape == (1, 4)
    # Rebuild the discrete model as the controller does and check the closed loop's spectrum.
    import scipy.linalg

    A = np.linalg.inv(np.array([[M + m_w + I_w / r**2, M * h], [M * h, I + M * h * h]]))
    g, b = A @ [0.0, M * 9.81 * h], A @ [1.0 / r, -1.0]
    Ac = np.zeros((4, 4))
    Ac[0, 2] = Ac[1, 3] = 1.0
    Ac[2:, 1] = g
    Bc = np.zeros((4, 1))
    Bc[2:, 0] = b
    aug = np.zeros((5, 5))
    aug[:4, :4], aug[:4, 4:] = Ac * dt, Bc * dt
    E = scipy.linalg.expm(aug)
    assert max(abs(np.linalg.eigvals(E[:4, :4]))) > 1.0  # open loop: it falls
    assert max(abs(np.linalg.eigvals(E[:4, :4] - E[:4, 4:] @ K))) < 1.0
    tau, phi = wip_feedforward(M, h, m_w, I_w, r, 0.2)
    assert tau > 0 and phi > 0.2 / 9.81  # leaning forward more than a/g: the wheel torque pitches it back


@pytest.mark.slow
def test_standing_still_and_recovering_from_a_push():
    robot = build_wheeled_robot("tita_piper")
    prof, m = robot.profile, robot.mj_model
    d = mujoco.MjData(m)
    place_robot(robot, d, prof.start_base, prof.start_arm)
    ctrl = BalanceController(m, prof.arm, prof.held, prof.wheels)
    q = measured_q(robot, d)[0]
    ref = Reference(q[:4].copy(), np.zeros(4), np.zeros(4), q[4:].copy(), np.zeros(3))
    pitches = []
    for i in range(6500):
        if i == 2000:
            d.qvel[0] += 0.3  # a 0.3 m/s shove forward
        ctrl.compute(d, ref)
        mujoco.mj_step(m, d)
        pitches.append(yaw_pitch_roll(d.qpos[3:7])[1])
        if i == 1999:
            # Standing: level and in place after the start transient.
            assert max(abs(p) for p in pitches[1000:]) < 1e-3
            assert abs(d.qpos[0] - q[0]) < 2e-3
    assert max(abs(p) for p in pitches[2000:]) > 1e-3  # the push did tip it
    assert max(abs(p) for p in pitches[2000:]) < 0.12  # 0.08 rad peak measured
    # Back, level and in place, within 4.5 s (about 3.5 s measured).
    assert abs(pitches[-1]) < 3e-4 and abs(d.qpos[0] - q[0]) < 1e-3
    assert d.qpos[2] > 0.35  # still standing
