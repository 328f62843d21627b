"""Eqs. (1)-(3) of seed 000 against values worked by hand, and the three mapping modes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.retarget.mapping import AbsoluteMap, IncrementalMap, rest_target, scale_up

# One operator/robot axis worked by hand:
#   H_s = 0.1, H_min = -0.2, H_max = 0.5 ; U_min = 0.0, U_max = 0.35
#   eq. (1): U_s = 0 + |0.1 - (-0.2)| / (0.5 - (-0.2)) * (0.35 - 0) = 0.3 / 0.7 * 0.35 = 0.15
#   eq. (3): M   = (0.35 - 0.15) / (0.5 - 0.1) = 0.2 / 0.4 = 0.5
#   eq. (2): H = 0.3  -> 0.15 + 0.5 * 0.2  = 0.25
#            H = -0.1 -> 0.15 + 0.5 * -0.2 = 0.05
#            H = 0.7  -> 0.15 + 0.5 * 0.6  = 0.45  (paper: beyond U_max, not clamped; bounded: 0.35)
#            H = -0.4 -> 0.15 + 0.5 * -0.5 = -0.1  (paper; bounded: 0.0)
AXIS = dict(H_s=0.1, H_min=-0.2, H_max=0.5, U_min=0.0, U_max=0.35)

# A second and third axis so the per-axis (vector) form is exercised with different numbers:
#   y: H_s = 0.0, H_min = -0.1, H_max = 0.4 ; U_min = -0.2, U_max = 0.3
#      U_s = -0.2 + 0.1 / 0.5 * 0.5 = -0.1 ; M = (0.3 + 0.1) / 0.4 = 1.0 ; H = 0.2 -> 0.1
#   z: H_s = -0.5, H_min = -0.6, H_max = 0.5 ; U_min = 0.1, U_max = 0.65
#      U_s = 0.1 + 0.1 / 1.1 * 0.55 = 0.15 ; M = (0.65 - 0.15) / 1.0 = 0.5 ; H = 0.0 -> 0.4
H_s = np.array([0.1, 0.0, -0.5])
H_min = np.array([-0.2, -0.1, -0.6])
H_max = np.array([0.5, 0.4, 0.5])
U_min = np.array([0.0, -0.2, 0.1])
U_max = np.array([0.35, 0.3, 0.65])


def test_eq1_rest_target_by_hand():
    np.testing.assert_allclose(rest_target(H_s, H_min, H_max, U_min, U_max), [0.15, -0.1, 0.15], atol=1e-12)


def test_eq3_scale_by_hand():
    U_s = np.array([0.15, -0.1, 0.15])
    np.testing.assert_allclose(scale_up(U_s, U_max, H_s, H_max), [0.5, 1.0, 0.5], atol=1e-12)


def test_eq2_paper_mapping_by_hand():
    m = AbsoluteMap.build("paper", H_s, H_min, H_max, U_min, U_max)
    U, clamped = m(np.array([0.3, 0.2, 0.0]))
    np.testing.assert_allclose(U, [0.25, 0.1, 0.4], atol=1e-12)
    assert not clamped.any()
    # below the rest on x: same scale M in paper mode
    U, _ = m(np.array([-0.1, 0.0, -0.5]))
    np.testing.assert_allclose(U, [0.05, -0.1, 0.15], atol=1e-12)


def test_paper_mode_is_literal_outside_the_extents_bounded_clamps():
    paper = AbsoluteMap.build("paper", H_s, H_min, H_max, U_min, U_max)
    bounded = AbsoluteMap.build("bounded", H_s, H_min, H_max, U_min, U_max)
    U, clamped = paper(np.array([0.7, 0.0, -0.5]))
    assert U[0] == pytest.approx(0.45) and not clamped.any()
    U, clamped = paper(np.array([-0.4, 0.0, -0.5]))
    assert U[0] == pytest.approx(-0.1)
    U, clamped = bounded(np.array([0.7, 0.0, -0.5]))
    assert U[0] == pytest.approx(0.35) and clamped[0] and not clamped[1:].any()
    U, clamped = bounded(np.array([-0.4, 0.0, -0.5]))
    assert U[0] == pytest.approx(0.0) and clamped[0]


def test_eq1_absolute_value_is_literal_in_paper_mode():
    # Rest below H_min (a bad calibration): H_s = -0.3, H_min = -0.2, H_max = 0.5, U in [0, 0.35].
    #   paper:   U_s = |-0.3 + 0.2| / 0.7 * 0.35 = 0.1 / 0.7 * 0.35 = 0.05 ; M = (0.35 - 0.05) / 0.8 = 0.375
    #   bounded: ratio clipped to 0 -> U_s = 0.0 ; M_up = 0.35 / 0.8 = 0.4375
    a = dict(H_min=-0.2, H_max=0.5, U_min=0.0, U_max=0.35)
    assert rest_target(-0.3, **a, literal=True) == pytest.approx(0.05)
    assert rest_target(-0.3, **a, literal=False) == pytest.approx(0.0)
    paper = AbsoluteMap.build("paper", -0.3, a["H_min"], a["H_max"], a["U_min"], a["U_max"])
    bounded = AbsoluteMap.build("bounded", -0.3, a["H_min"], a["H_max"], a["U_min"], a["U_max"])
    assert paper.M_up == pytest.approx(0.375)
    assert bounded.M_up == pytest.approx(0.4375)
    assert paper(np.array(0.5))[0] == pytest.approx(0.35)  # H_max still reaches U_max


def test_eqs_1_to_3_map_the_extents_affinely_by_hand():
    # With U_s from eq. (1) the upper-side scale of eq. (3) equals the lower-side one, so (1)-(3)
    # are the affine map [H_min, H_max] -> [U_min, U_max] (see mapping.py). Worked by hand:
    #   H_s = 0.3 on [-0.2, 0.5], U on [0, 0.35]: U_s = 0.5 / 0.7 * 0.35 = 0.25
    #   below: (0.25 - 0) / (0.3 + 0.2) = 0.5 ; above (eq. 3): (0.35 - 0.25) / (0.5 - 0.3) = 0.5
    m = AbsoluteMap.build("bounded", 0.3, -0.2, 0.5, 0.0, 0.35)
    assert m.U_s == pytest.approx(0.25)
    assert m.M_down == pytest.approx(0.5) and m.M_up == pytest.approx(0.5)
    assert m(np.array(-0.2))[0] == pytest.approx(0.0)
    assert m(np.array(0.5))[0] == pytest.approx(0.35)
    assert m(np.array(0.0))[0] == pytest.approx(0.1)  # 0.25 + 0.5 * (0.0 - 0.3)


def test_degenerate_inputs_are_clear_errors():
    with pytest.raises(ValueError, match="H_min < H_max"):
        rest_target(0.0, 0.2, 0.2, 0.0, 1.0)
    with pytest.raises(ValueError, match="H_s < H_max"):
        scale_up(0.0, 1.0, 0.5, 0.5)
    with pytest.raises(ValueError, match="known: paper, bounded"):
        AbsoluteMap.build("magic", H_s, H_min, H_max, U_min, U_max)
    with pytest.raises(ValueError, match="U_min < U_max"):
        AbsoluteMap.build("paper", H_s, H_min, H_max, U_max, U_min)


boxes = st.tuples(
    st.floats(-1.0, 1.0), st.floats(0.05, 1.0), st.floats(0.05, 1.0), st.floats(-1.0, 1.0), st.floats(0.05, 1.0)
)


@settings(max_examples=200, deadline=None)
@given(boxes, st.floats(0.0, 1.0))
def test_bounded_mapping_stays_in_the_box_and_is_monotonic(box, u):
    h_lo, below, above, u_lo, u_span = box
    h_s = h_lo + below
    m = AbsoluteMap.build("bounded", h_s, h_lo, h_s + above, u_lo, u_lo + u_span)
    H = np.linspace(h_lo - 0.5, h_s + above + 0.5, 50)
    U, _ = m(H)
    assert np.all(u_lo - 1e-12 <= U) and np.all(u_lo + u_span + 1e-12 >= U)
    assert np.all(np.diff(U) >= -1e-12)
    # the extents map onto the box ends
    assert m(np.array(h_lo))[0] == pytest.approx(u_lo, abs=1e-9)
    assert m(np.array(h_s + above))[0] == pytest.approx(u_lo + u_span, abs=1e-9)


def test_incremental_mode_adds_scaled_deltas_and_reanchors():
    m = IncrementalMap(np.array([0.1, 0.2, 0.3]), k=0.5, U_min=np.full(3, -1.0), U_max=np.full(3, 1.0))
    U, _ = m(np.array([1.0, 1.0, 1.0]))  # first sample only anchors
    np.testing.assert_allclose(U, [0.1, 0.2, 0.3])
    U, _ = m(np.array([1.2, 0.8, 1.0]))  # dH = (0.2, -0.2, 0) -> + (0.1, -0.1, 0)
    np.testing.assert_allclose(U, [0.2, 0.1, 0.3])
    m.reanchor()
    U, _ = m(np.array([5.0, 5.0, 5.0]))  # after a dropout: no jump
    np.testing.assert_allclose(U, [0.2, 0.1, 0.3])
    U, clamped = m(np.array([9.0, 5.0, 5.0]))  # +2.0 on x -> clamped to 1.0
    np.testing.assert_allclose(U, [1.0, 0.1, 0.3])
    assert clamped.tolist() == [True, False, False]
    U, _ = m(np.array([8.0, 5.0, 5.0]))  # the clamped state moves back at once
    np.testing.assert_allclose(U, [0.5, 0.1, 0.3])
