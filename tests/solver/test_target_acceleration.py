"""The tracker's parabolic extrapolation (``TargetTracker(acceleration=True)``): known answers.

A target on a parabola ``p(t) = p0 + a t^2 / 2``, published at 30 fps with the retargeter's velocities (backward
differences, the velocity half a frame back), is predicted exactly between frames and at the next frame once the
share fit has seen one frame; at constant velocity it misses by ``a D^2``. Velocities that are jitter (a still
target whose velocity alternates in sign) give the acceleration no share: the extrapolation stays at constant
velocity.
"""

from __future__ import annotations

import numpy as np
import pytest

from services.solver.core import SolverConfig
from services.solver.targets import TargetTracker
from shared.messages import Header, Target, TaskTargets

D = 1.0 / 30.0
P0 = np.array([0.3, -0.2, 0.1])
ACC = np.array([4.0, -2.0, 6.0])  # m/s^2: a wave's turnaround


def _message(seq: int, p: np.ndarray, v: np.ndarray) -> TaskTargets:
    return TaskTargets(Header(seq, seq * D), {"left_wrist": Target(p, np.array([1.0, 0, 0, 0]), v, np.zeros(3))})


def _parabola(t: float) -> np.ndarray:
    return P0 + 0.5 * ACC * t * t


def _feed_parabola(tracker: TargetTracker, frames: int) -> None:
    for k in range(frames):
        t = k * D
        v = (_parabola(t) - _parabola(t - D)) / D  # backward difference: the velocity at t - D/2
        tracker.update(_message(k, _parabola(t), v), t)


@pytest.mark.parametrize(("acceleration", "memory"), [(True, 10.0), (True, 0.0), (False, 10.0)])
def test_parabola_is_predicted_between_and_at_frames(acceleration: bool, memory: float):
    tracker = TargetTracker(horizon=0.05, acceleration=acceleration, acceleration_memory=memory)
    _feed_parabola(tracker, 6)
    t_last = 5 * D
    for tau in (0.0, 0.5 * D, D):
        s = tracker.sample("left_wrist", t_last + tau)
        miss = np.linalg.norm(s.p - _parabola(t_last + tau))
        if acceleration:
            assert miss < 1e-12
            np.testing.assert_allclose(s.v, ACC * (t_last + tau), atol=1e-9)  # the parabola's own velocity
        elif tau == D:
            # constant velocity: the backward difference extrapolated misses by a D^2 (0.3 cm here)
            assert miss == pytest.approx(np.linalg.norm(ACC) * D * D, rel=1e-9)


def test_jittering_velocities_get_no_acceleration():
    tracker = TargetTracker(horizon=0.05, acceleration=True)
    for k in range(20):
        tracker.update(_message(k, P0.copy(), np.array([0.05, 0.0, 0.0]) * (-1) ** k), k * D)
    s = tracker.sample("left_wrist", 19 * D + 0.5 * D)
    v_last = np.array([0.05, 0.0, 0.0]) * (-1) ** 19
    np.testing.assert_allclose(s.p, P0 + v_last * 0.5 * D)  # constant velocity, no parabola
    np.testing.assert_allclose(s.v, v_last)


def test_a_gap_or_a_held_target_restarts_at_constant_velocity():
    tracker = TargetTracker(horizon=0.05, acceleration=True)
    _feed_parabola(tracker, 6)
    v = np.array([0.1, 0.0, 0.0])
    # the next frame 0.2 s later (a dropout): no acceleration across it
    tracker.update(
        TaskTargets(Header(6, 5 * D + 0.2), {"left_wrist": Target(P0, np.array([1.0, 0, 0, 0]), v, np.zeros(3))}), 1.0
    )
    np.testing.assert_allclose(tracker.sample("left_wrist", 1.01).p, P0 + v * 0.01)


def test_the_solver_config_selects_it():
    assert TargetTracker.for_solver(SolverConfig()).acceleration  # on by default since session 11
    assert not TargetTracker.for_solver(SolverConfig(target_acceleration=False)).acceleration
    tracker = TargetTracker.for_solver(SolverConfig(target_acceleration=True, target_acceleration_memory=5))
    assert tracker.acceleration and tracker.acceleration_memory == 5


def test_negative_lag_or_memory_is_refused():
    with pytest.raises(ValueError, match="target_velocity_lag"):
        SolverConfig(target_velocity_lag=-0.5)
    with pytest.raises(ValueError, match="target_acceleration_memory"):
        SolverConfig(target_acceleration_memory=-1)
