"""DBSCAN through voxels (instances/voxel_dbscan.py) against scikit-learn's per-point DBSCAN, and
the ground cells' heights (instances/ground.py) against a per-cell sort."""

from __future__ import annotations

import numpy as np
from sklearn.cluster import DBSCAN
from sklearn.metrics import adjusted_rand_score

from idsplat_ns.instances.ground import cell_heights, cell_keys
from idsplat_ns.instances.voxel_dbscan import dbscan, voxel_centres, voxel_dbscan


def _street_points(rng: np.random.Generator) -> np.ndarray:  # -> [N, 3]
    """Dense box surfaces (cars, a wall) a few metres apart, and sparse noise between them."""
    parts = []
    for centre, size, count in (((5, 2, 1), (4.5, 1.8, 1.4), 6000), ((14, -3, 1), (4.0, 1.8, 1.5), 3000),
                                ((9, 8, 2), (20.0, 0.3, 4.0), 9000), ((30, 0, 1.5), (12.0, 2.5, 3.0), 800)):
        p = rng.uniform(-0.5, 0.5, (count, 3)) * size + centre
        face = rng.integers(0, 3, count)
        p[np.arange(count), face] = np.asarray(centre)[face] + np.sign(rng.normal(size=count)) * np.asarray(size)[face] / 2
        parts.append(p)
    parts.append(rng.uniform([-5, -10, 0.3], [40, 10, 3], (40, 3)))  # isolated points: noise
    return np.concatenate(parts)


def test_voxels_give_the_partition_of_per_point_dbscan():
    rng = np.random.default_rng(0)
    points = _street_points(rng)
    reference = DBSCAN(eps=0.7, min_samples=5).fit_predict(points)
    labels = voxel_dbscan(points, 0.7, 5, 0.1)
    assert len(np.unique(reference[reference >= 0])) >= 4
    assert adjusted_rand_score(reference, labels) > 0.999
    assert np.array_equal(labels < 0, reference < 0)  # the same noise points
    # 0: plain DBSCAN: the same clusters of the core samples and the same noise (a border sample
    # within reach of two clusters may go either way in DBSCAN).
    plain = voxel_dbscan(points, 0.7, 5, 0.0)
    core = DBSCAN(eps=0.7, min_samples=5).fit(points).core_sample_indices_
    assert adjusted_rand_score(reference[core], plain[core]) == 1.0
    assert np.array_equal(plain < 0, reference < 0) and adjusted_rand_score(reference, plain) > 0.9999
    assert len(voxel_dbscan(np.zeros((0, 3)), 0.7, 5, 0.1)) == 0


def test_weights_count_as_that_many_samples_at_the_point():
    rng = np.random.default_rng(2)
    points = _street_points(rng)[::7]
    weights = rng.integers(1, 4, len(points))
    repeated = np.repeat(points, weights, axis=0)  # each sample that many times: the unweighted twin
    reference = DBSCAN(eps=0.7, min_samples=6).fit_predict(repeated)
    labels = dbscan(points, 0.7, 6, weights)
    assert adjusted_rand_score(reference, np.repeat(labels, weights)) > 0.999
    assert np.array_equal(np.repeat(labels, weights) < 0, reference < 0)
    assert np.array_equal(dbscan(points, 0.7, 6, weights), labels)  # deterministic


def test_a_voxel_of_min_samples_points_is_a_core_sample():
    # Five points in one voxel, alone: one cluster, as DBSCAN finds them; four: noise.
    five = np.array([[0.01, 0.0, 0.0], [0.02, 0.01, 0.0], [0.0, 0.03, 0.01], [0.03, 0.03, 0.0], [0.0, 0.0, 0.02]])
    assert (voxel_dbscan(five, 0.7, 5, 0.1) == 0).all() and (DBSCAN(eps=0.7, min_samples=5).fit_predict(five) == 0).all()
    assert (voxel_dbscan(five[:4], 0.7, 5, 0.1) == -1).all()


def test_voxel_centres_are_the_means_of_their_points():
    points = np.array([[0.01, 0.01, 0.01], [0.09, 0.05, 0.03], [0.31, 0.0, 0.0], [-0.05, 0.0, 0.0]])
    centres, counts, inverse = voxel_centres(points, 0.1)
    assert counts.sum() == 4 and inverse[0] == inverse[1] and len({*inverse.tolist()}) == 3
    assert np.allclose(centres[inverse[0]], [0.05, 0.03, 0.02]) and np.allclose(centres[inverse[2]], points[2])


def test_cell_heights_are_the_rank_th_lowest_over_all_chunks():
    rng = np.random.default_rng(1)
    chunks = [rng.uniform([-3, -3, -1], [3, 3, 2], (int(n), 3)) for n in rng.integers(0, 400, 6)]
    keys, heights = cell_heights(chunks, 0.5, 2)
    allp = np.concatenate(chunks)
    k_all = cell_keys(allp[:, :2], 0.5)
    assert np.array_equal(keys, np.unique(k_all))
    for key, h in zip(keys, heights):
        z = np.sort(allp[k_all == key, 2])
        assert h == z[min(2, len(z) - 1)]  # the third lowest, or the highest of fewer
    assert len(cell_heights([np.zeros((0, 3))], 0.5, 2)[0]) == 0
