"""Train / evaluation frame splits (data/split.py): linearly spaced held-out frames and every k-th frame."""

import math

import numpy as np
import pytest

from idsplat_ns.data.split import split_frames
from idsplat_ns.errors import IDSplatError


@pytest.mark.parametrize("num,frac", [(80, 0.5), (50, 0.75), (50, 0.9), (100, 0.25), (7, 0.5)])
def test_fractions_are_disjoint_covering_and_spread(num, frac):
    train, ev = split_frames(num, frac)
    assert len(set(train) & set(ev)) == 0
    assert sorted(np.concatenate([train, ev]).tolist()) == list(range(num))
    assert len(train) == round(frac * num)
    assert 0 not in ev and num - 1 not in ev  # evaluation interpolates between training frames
    # Spread over the whole sequence: with the two ends, no stretch between evaluation frames is
    # longer than their even spacing (num - 1) / (len(ev) + 1), plus one frame of rounding.
    gaps = np.diff(np.concatenate([[0], ev, [num - 1]]))
    assert gaps.max() <= math.ceil((num - 1) / (len(ev) + 1)) + 1
    assert np.ptp(np.diff(ev)) <= 1  # and evenly: steps between them differ by one frame at most


def test_linearly_spaced_frames_by_hand():
    # 20 frames, 10 held out, strictly inside: 19 k / 11 for k = 1..10 = 1.73, 3.45, 5.18, 6.91,
    # 8.64, 10.36, 12.09, 13.82, 15.55, 17.27, rounded.
    train, ev = split_frames(20, 0.5)
    assert ev.tolist() == [2, 3, 5, 7, 9, 10, 12, 14, 16, 17]
    assert train.tolist() == [0, 1, 4, 6, 8, 11, 13, 15, 18, 19]
    # 50 frames at 75 %: 38 train, 12 held out at 49 k / 13 = 3.77, 7.54, 11.31, ... 45.23.
    _, ev = split_frames(50, 0.75)
    assert ev.tolist() == [4, 8, 11, 15, 19, 23, 26, 30, 34, 38, 41, 45]


def test_full_fraction_and_every_k():
    train, ev = split_frames(12, 1.0)
    assert train.tolist() == ev.tolist() == list(range(12))
    train, ev = split_frames(20, eval_every=4)
    assert ev.tolist() == [0, 4, 8, 12, 16]
    train, ev = split_frames(10, eval_every=4, eval_offset=1)
    assert ev.tolist() == [1, 5, 9] and train.tolist() == [0, 2, 3, 4, 6, 7, 8]
    with pytest.raises(IDSplatError):
        split_frames(10, 0.0)
    with pytest.raises(IDSplatError, match="eval_every"):
        split_frames(10, eval_every=1)
