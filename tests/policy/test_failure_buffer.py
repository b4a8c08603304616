"""Failure buffer semantics: rows are independent, the cap forgets the oldest, clearing is per row."""

import torch

from lerobot_ccdp.policy.failure_buffer import FailureBuffer, distinct_failures


def test_rows_are_independent_and_padded_masks_match_counts():
    buf = FailureBuffer(batch_size=3, feature_dim=2, cap=4)
    buf.add(torch.tensor([True, False, True]), torch.tensor([[1.0, 1], [9, 9], [3, 3]]))
    buf.add(torch.tensor([True, False, False]), torch.tensor([[2.0, 2], [9, 9], [9, 9]]))
    z, mask = buf.padded()
    assert buf.count.tolist() == [2, 0, 1]
    assert mask.tolist() == [[True, True], [False, False], [True, False]]
    assert z[0].tolist() == [[1, 1], [2, 2]] and z[2, 0].tolist() == [3, 3]
    assert not (z[1] == 9).any()


def test_cap_forgets_the_oldest_failure():
    buf = FailureBuffer(batch_size=1, feature_dim=1, cap=3)
    for value in range(5):
        buf.add(torch.tensor([True]), torch.tensor([[float(value)]]))
    z, mask = buf.padded()
    assert mask.all() and z.flatten().tolist() == [2.0, 3.0, 4.0]


def test_clear_one_row_keeps_the_others():
    buf = FailureBuffer(batch_size=2, feature_dim=1, cap=2)
    buf.add(torch.tensor([True, True]), torch.ones(2, 1))
    buf.clear(torch.tensor([True, False]))
    assert buf.count.tolist() == [0, 1]
    z, mask = buf.padded(torch.tensor([True, False]))
    assert z.shape == (1, 0, 1) and mask.shape == (1, 0)


def test_distinct_failures_drop_a_repeat_of_an_earlier_failure_of_the_same_row():
    z = torch.tensor(
        [
            [[0.0, 0.0], [1.0, 0.0], [0.05, 0.0], [0.0, 0.0]],  # the third is near the first: a repeat
            [[0.0, 0.0], [0.0, 0.0], [3.0, 3.0], [9.0, 9.0]],  # the second repeats the first; slot 4 unused
        ]
    )
    mask = torch.tensor([[True, True, True, True], [True, True, True, False]])
    distinct = distinct_failures(z, mask, delta_z=0.01)
    assert distinct.tolist() == [[True, True, False, False], [True, False, True, False]]
    assert distinct_failures(z, mask, delta_z=0.0).tolist() == [
        [True, True, True, False],
        [True, False, True, False],
    ]
