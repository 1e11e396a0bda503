"""DBSCAN of dense lidar points through voxels.

A real sweep (Waymo: 64 x 2,650 rays) puts 60-80k points above the ground. Clustered point by
point, DBSCAN's time grows with the points times their neighbours, so with the square of the
density. Points are first merged into voxels much smaller than the neighbourhood radius; the
voxels' mean positions are clustered with their point counts as weights (a voxel of
``min_samples`` points is a core sample by itself, as those points are), and every point takes its
voxel's label. Time then follows the surfaces seen, not the density. On the segment-size street,
0.1 m voxels gave the partition of per-point DBSCAN on every sweep tested (adjusted Rand index
1.0000).

The clustering is written here, not scikit-learn's ``DBSCAN``: with sample weights that one sums
each neighbourhood in a Python loop over the samples, half of its 0.46 s a sweep; the pair list
of a KD-tree and the connected components of scipy take 0.23 s. tests/test_voxel_dbscan.py
compares the two.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def dbscan(points: np.ndarray, eps: float, min_samples: float, weights: np.ndarray | None = None) -> np.ndarray:
    """DBSCAN labels [N] (0, 1, ...; -1: noise) of ``points`` [N, 3] with sample ``weights`` [N]
    (default 1). A core sample has neighbours (itself included) within ``eps`` weighing at least
    ``min_samples``; clusters are the core samples joined through each other, and the border
    samples within ``eps`` of a core sample (each takes the cluster of its first core neighbour
    by index)."""
    n = len(points)
    w = np.ones(n) if weights is None else np.asarray(weights, np.float64)
    if n == 0:
        return np.zeros(0, np.int64)
    pairs = cKDTree(points).query_pairs(eps, output_type="ndarray")  # [P, 2], i < j
    a, b = pairs[:, 0], pairs[:, 1]
    mass = w + np.bincount(a, weights=w[b], minlength=n) + np.bincount(b, weights=w[a], minlength=n)
    core = mass >= min_samples
    joined = core[a] & core[b]
    graph = coo_matrix((np.ones(int(joined.sum())), (a[joined], b[joined])), shape=(n, n))
    _, component = connected_components(graph, directed=False)
    labels = np.full(n, -1, np.int64)
    labels[core] = np.unique(component[core], return_inverse=True)[1].reshape(-1)
    # Border samples: non-core with a core neighbour; the neighbour of lowest index decides.
    edge = core[a] ^ core[b]
    inner = np.where(core[a[edge]], a[edge], b[edge])
    border = np.where(core[a[edge]], b[edge], a[edge])
    order = np.lexsort((inner, border))
    border, inner = border[order], inner[order]
    first = np.r_[True, border[1:] != border[:-1]] if len(border) else np.zeros(0, bool)
    labels[border[first]] = labels[inner[first]]
    return labels


def voxel_centres(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The occupied voxels of side ``voxel`` of ``points`` [N, 3]: their mean points [V, 3], their
    point counts [V] and each point's voxel [N]."""
    cells = np.floor(points / voxel).astype(np.int64)
    cells -= cells.min(0)
    span = cells.max(0) + 1
    if np.prod(span.astype(np.float64)) < 2.0**62:  # one sortable integer per voxel: a 1-D unique
        keys = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
        _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    else:
        _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    centres = np.stack([np.bincount(inverse, weights=points[:, d], minlength=len(counts)) for d in range(3)], axis=1)
    return centres / counts[:, None], counts, inverse


def voxel_dbscan(points: np.ndarray, eps: float, min_samples: int, voxel: float) -> np.ndarray:
    """DBSCAN labels [N] of ``points`` [N, 3] (-1: noise), clustered as voxels of side ``voxel``
    weighted by their point counts (0: each point)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0 or voxel <= 0:
        return dbscan(points, eps, min_samples)
    centres, counts, inverse = voxel_centres(points, voxel)
    return dbscan(centres, eps, min_samples, counts)[inverse]
