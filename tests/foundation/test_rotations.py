"""shared.rotations: quat_to_matrix against the steps it stands for."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shared.rotations import quat_to_matrix


def test_quat_to_matrix_normalises_with_the_bits_of_linalg_norm():
    """The norm as ``sqrt(q . q)`` (cheaper than np.linalg.norm on a tick) gives the same matrices, bit for bit,
    over quaternions of norms 1e-3 to 1e3, including unit ones."""
    rng = np.random.default_rng(7)
    Q = rng.standard_normal((5000, 4)) * 10.0 ** rng.uniform(-3, 3, (5000, 1))
    Q[::10] /= np.linalg.norm(Q[::10], axis=1, keepdims=True)
    for q in Q:
        ref = np.empty(9)
        mujoco.mju_quat2Mat(ref, q / float(np.linalg.norm(q)))
        np.testing.assert_array_equal(quat_to_matrix(q), ref.reshape(3, 3))


@pytest.mark.parametrize("q", [np.zeros(4), np.array([np.nan, 0, 0, 1.0]), np.array([np.inf, 0, 0, 1.0])])
def test_quat_to_matrix_rejects_a_quaternion_without_rotation(q):
    with pytest.raises(ValueError, match="no rotation"):
        quat_to_matrix(q)
