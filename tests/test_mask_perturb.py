"""Noisy instance masks (instances/masks/perturb.py): each kind of damage does what it says."""

from __future__ import annotations

import cv2
import numpy as np

from idsplat_ns.instances.masks.perturb import MaskNoiseConfig, perturb_instance_map


def _two_boxes() -> np.ndarray:
    ids = np.zeros((40, 60), np.uint16)
    ids[5:20, 5:25] = 3
    ids[22:35, 30:55] = 7
    return ids


def test_identity_swap_exchanges_two_ids_and_nothing_else() -> None:
    ids = _two_boxes()
    config = MaskNoiseConfig(max_edge_px=0, miss_probability=0.0, swap_probability=1.0)
    out = perturb_instance_map(ids, config, np.random.default_rng(0))
    assert np.array_equal(out == 7, ids == 3) and np.array_equal(out == 3, ids == 7)
    kept = perturb_instance_map(ids, MaskNoiseConfig(max_edge_px=0, miss_probability=0.0), np.random.default_rng(0))
    assert np.array_equal(kept, ids)  # swap_probability 0: untouched


def test_missed_instances_and_edges_stay_within_their_bounds() -> None:
    ids = _two_boxes()
    assert not perturb_instance_map(ids, MaskNoiseConfig(miss_probability=1.0), np.random.default_rng(1)).any()
    r = 3
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    for seed in range(5):
        out = perturb_instance_map(ids, MaskNoiseConfig(max_edge_px=r, miss_probability=0.0), np.random.default_rng(seed))
        for k in (3, 7):
            m = (ids == k).astype(np.uint8)
            grown, shrunk = cv2.dilate(m, kernel) > 0, cv2.erode(m, kernel) > 0
            assert np.all(grown[out == k]) and np.all((out == k)[shrunk])
