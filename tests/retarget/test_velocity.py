"""The target velocity filter."""

from __future__ import annotations

import numpy as np
import pytest

from services.retarget.velocity import LowPassVelocity


def test_constant_velocity_converges_and_noise_is_reduced():
    rng = np.random.default_rng(1)
    dt, v_true = 1 / 60, np.array([0.3, -0.1, 0.05])
    f_raw, f = LowPassVelocity(tau=0.0), LowPassVelocity(tau=0.05)
    p_prev = None
    raw_out, filt_out = [], []
    for i in range(300):
        p = v_true * i * dt + rng.normal(scale=1e-3, size=3)  # 1 mm jitter
        rate = None if p_prev is None else (p - p_prev) / dt
        raw_out.append(f_raw.update(rate, dt))
        filt_out.append(f.update(rate, dt))
        p_prev = p
    raw_out, filt_out = np.array(raw_out[100:]), np.array(filt_out[100:])
    np.testing.assert_allclose(filt_out.mean(axis=0), v_true, atol=0.01)
    assert np.all(filt_out.std(axis=0) < 0.5 * raw_out.std(axis=0))


def test_first_order_step_response():
    # a = dt / (tau + dt) = 0.01 / 0.05 = 0.2 per step on a unit step
    f = LowPassVelocity(tau=0.04)
    f.update(None, 0.01)
    out = [f.update(np.ones(3), 0.01)[0] for _ in range(3)]
    np.testing.assert_allclose(out, [0.2, 0.36, 0.488])


def test_gap_and_reset_restart_from_zero():
    f = LowPassVelocity(tau=0.0, max_gap=0.2)
    assert f.update(np.ones(3), 0.01)[0] == pytest.approx(1.0)
    assert np.all(f.update(np.ones(3), 0.5) == 0.0)  # dropout: no velocity across the gap
    with pytest.raises(ValueError):
        LowPassVelocity(tau=-1.0)
