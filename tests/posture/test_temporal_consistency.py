"""The training option ``--temporal-weight``: the samples' tick order and the temporal-consistency term."""

from __future__ import annotations

import numpy as np
import pytest

from services.posture.rollout import Rollout
from services.posture.train import Dataset, _successor, from_rollouts


def _rollout(label_ok: np.ndarray, first: float) -> Rollout:
    """A rollout of K ticks whose state's first entry numbers the ticks from ``first`` (both arms)."""
    K = len(label_ok)
    S = np.zeros((K, 2, 14))
    S[:, :, 0] = first + np.arange(K)[:, None]
    zeros = np.zeros((K, 2))
    return Rollout(S, np.zeros((K, 2, 3)), np.zeros((K, 2, 3)), np.zeros((K, 2, 6)), label_ok, zeros, zeros, zeros)


def test_successors_follow_ticks_of_one_rollout_through_gaps_mirroring_and_rounds(robot14):
    from shared.mirror import mirror_signs

    ok = np.ones((5, 2), dtype=bool)
    ok[2, 0] = False  # the left arm's tick 2 has no label: ticks 1 and 3 are not consecutive
    d = from_rollouts([_rollout(ok, 0.0), _rollout(np.ones((2, 2), dtype=bool), 100.0)])
    # left rows: ticks 0 1 3 4 | 100 101; right rows: ticks 0 1 2 3 4 | 100 101
    np.testing.assert_array_equal(d.nxt[0], [1, -1, 3, -1, 5, -1])
    np.testing.assert_array_equal(d.nxt[1], [1, 2, 3, 4, -1, 6, -1])
    for i in range(2):  # a successor is always the next tick of the same rollout
        has = d.nxt[i] >= 0
        np.testing.assert_array_equal(d.S[i][d.nxt[i][has], 0], d.S[i][has, 0] + 1)
    r = d.add(d.S, d.A, d.Z, d.nxt)  # a relabelling round appends: its rows shift by the rows before them
    np.testing.assert_array_equal(r.nxt[0], [1, -1, 3, -1, 5, -1, 7, -1, 9, -1, 11, -1])
    m = d.with_mirror(mirror_signs(robot14), "elbow")  # the left arm gets the right arm's rows after its 6
    np.testing.assert_array_equal(m.nxt[0], [1, -1, 3, -1, 5, -1, 7, 8, 9, 10, -1, 12, -1])
    np.testing.assert_array_equal(m.nxt[1][7:], [8, -1, 10, -1, 12, -1])
    assert Dataset(d.S, d.A, d.Z).add(d.S, d.A, d.Z, d.nxt).nxt is None  # order unknown stays unknown
    # --temporal-ticks 2 and 3: two / three ticks on, within the rollout; the label gap breaks the chain
    np.testing.assert_array_equal(_successor(d.nxt[1], 2), [2, 3, 4, -1, -1, -1, -1])
    np.testing.assert_array_equal(_successor(d.nxt[1], 3), [3, 4, -1, -1, -1, -1, -1])
    np.testing.assert_array_equal(_successor(d.nxt[0], 2), [-1] * 6)


def test_temporal_term_is_the_change_of_the_prediction_minus_the_change_of_the_label():
    torch = pytest.importorskip("torch", reason="training needs the optional extra: pip install 'mimic[train]'")
    from services.posture.train import _temporal_loss

    S = torch.tensor([[0.0, 0.0], [1.0, 0.0], [3.0, 1.0], [5.0, 1.0]])
    A = torch.tensor([[0.0, 0.0], [1.0, 1.0], [0.0, 0.0], [0.0, 4.0]])
    nxt = torch.tensor([1, -1, 3, -1])

    def enc(x):  # π(s) = 2 s
        return 2.0 * x

    # pairs (0, 1): Δπ = (2, 0), Δa = (1, 1) -> (1, -1); (2, 3): Δπ = (4, 0), Δa = (0, 4) -> (4, -4)
    full = float(_temporal_loss(enc, S, A, torch.arange(4), nxt))
    assert full == pytest.approx((1 + 1 + 16 + 16) / 4)  # mean over the pairs' entries
    assert float(_temporal_loss(enc, S, A, torch.tensor([2, 1]), nxt)) == pytest.approx(16.0)  # row 1 has none
    assert float(_temporal_loss(enc, S, A, torch.tensor([1, 3]), nxt)) == 0.0
