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
    gaps = np.diff(ev)
    assert gaps.max() - gaps.min() <= 1 if len(ev) > 2 else True  # linearly spaced


def test_half_split_alternates():
    train, ev = split_frames(10, 0.5)
    assert len(ev) == 5 and len(train) == 5


def test_full_fraction_and_every_k():
    train, ev = split_frames(12, 1.0)
    assert train.tolist() == ev.tolist() == list(range(12))
    train, ev = split_frames(20, eval_every=4)
    assert ev.tolist() == [0, 4, 8, 12, 16]
    with pytest.raises(IDSplatError):
        split_frames(10, 0.0)
