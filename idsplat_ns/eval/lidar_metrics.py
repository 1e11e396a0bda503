"""Lidar novel-view metrics of the paper's Table 2 (as in SplatAD / NeuRAD), in numpy.

Definitions (R rays of one evaluated sweep; a ray is *predicted returned* when its predicted
ray-drop probability is below ``drop_threshold`` = 0.5):

* ``depth_median_sq``: median over rays that returned in the ground truth **and** are predicted
  returned of ``(predicted range - measured range)^2`` (m^2).
* ``intensity_rmse``: ``sqrt(mean((predicted intensity - measured intensity)^2))`` over rays
  that returned in the ground truth.
* ``ray_drop_accuracy``: fraction of all rays whose predicted drop (``p >= 0.5``) equals the
  ground-truth drop (no return).
* ``chamfer``: Chamfer distance between the predicted points ``o + d * predicted range`` of the
  predicted-returned rays and the ground-truth points of the returned rays:
  ``0.5 * (mean_p min_q |p - q| + mean_q min_p |q - p|)`` with Euclidean (not squared)
  distances in metres.

A metric whose ray set is empty is NaN. Per-sweep values are averaged over sweeps by the caller.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def chamfer_distance(a: np.ndarray, b: np.ndarray) -> float:  # a: [M, 3], b: [K, 3]
    """Symmetric Chamfer distance: mean of the two directed mean nearest-neighbour distances."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 3)
    if len(a) == 0 or len(b) == 0:
        return float("nan")
    a_to_b = cKDTree(b).query(a, k=1)[0]
    b_to_a = cKDTree(a).query(b, k=1)[0]
    return float(0.5 * (a_to_b.mean() + b_to_a.mean()))


def lidar_metrics(
    pred_range: np.ndarray,  # [R] metres from the ray origin
    pred_intensity: np.ndarray,  # [R]
    pred_drop_prob: np.ndarray,  # [R] probability of no return
    gt_range: np.ndarray,  # [R] metres (ignored where not returned)
    gt_intensity: np.ndarray,  # [R]
    gt_returned: np.ndarray,  # [R] bool
    origins: np.ndarray,  # [R, 3] world
    directions: np.ndarray,  # [R, 3] world unit directions
    drop_threshold: float = 0.5,
) -> dict[str, float]:
    """The four lidar metrics of one sweep (see the module docstring for the definitions)."""
    pred_range = np.asarray(pred_range, dtype=np.float64).reshape(-1)
    pred_intensity = np.asarray(pred_intensity, dtype=np.float64).reshape(-1)
    pred_drop = (
        np.asarray(pred_drop_prob, dtype=np.float64).reshape(-1) >= drop_threshold
    )
    gt_range = np.asarray(gt_range, dtype=np.float64).reshape(-1)
    gt_intensity = np.asarray(gt_intensity, dtype=np.float64).reshape(-1)
    gt_ret = np.asarray(gt_returned, dtype=bool).reshape(-1)
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    pred_ret = ~pred_drop

    both = gt_ret & pred_ret
    depth = (
        float(np.median((pred_range[both] - gt_range[both]) ** 2))
        if both.any()
        else float("nan")
    )
    inten = (
        float(np.sqrt(np.mean((pred_intensity[gt_ret] - gt_intensity[gt_ret]) ** 2)))
        if gt_ret.any()
        else float("nan")
    )
    acc = float(np.mean(pred_drop == ~gt_ret)) if len(gt_ret) else float("nan")
    pred_pts = origins[pred_ret] + directions[pred_ret] * pred_range[pred_ret, None]
    gt_pts = origins[gt_ret] + directions[gt_ret] * gt_range[gt_ret, None]
    return {
        "depth_median_sq": depth,
        "intensity_rmse": inten,
        "ray_drop_accuracy": acc,
        "chamfer": chamfer_distance(pred_pts, gt_pts),
    }


def range_error_by_distance(
    gt_range: np.ndarray,  # [K] measured range of rays returned in both, metres
    abs_error: np.ndarray,  # [K] |predicted - measured| range, metres
    bin_width: float = 10.0,
) -> dict[str, np.ndarray]:
    """The absolute range error in bins of measured range ``[0, w), [w, 2w), ...`` up to the
    farthest ray: ``edges`` [B+1], and per bin ``count``, ``median``, ``p25``, ``p75`` [B]
    (NaN where a bin is empty). Medians, as the depth metric, so that a few mixed pixels on an
    edge do not swamp a bin."""
    gt_range = np.asarray(gt_range, dtype=np.float64).reshape(-1)
    abs_error = np.asarray(abs_error, dtype=np.float64).reshape(-1)
    if gt_range.shape != abs_error.shape:
        raise ValueError(f"range_error_by_distance: {gt_range.shape} ranges against {abs_error.shape} errors")
    if bin_width <= 0:
        raise ValueError(f"range_error_by_distance: bin width must be positive, got {bin_width}")
    keep = np.isfinite(gt_range) & np.isfinite(abs_error)
    gt_range, abs_error = gt_range[keep], abs_error[keep]
    top = max(float(gt_range.max()) if gt_range.size else 0.0, 0.0)
    nbins = max(int(np.floor(top / bin_width)) + 1, 1)
    edges = np.arange(nbins + 1, dtype=np.float64) * bin_width
    which = np.minimum((gt_range // bin_width).astype(np.int64), nbins - 1)
    count = np.bincount(which, minlength=nbins)
    stats = np.full((3, nbins), np.nan)
    for b in np.flatnonzero(count):
        stats[:, b] = np.percentile(abs_error[which == b], [50, 25, 75])
    return {"edges": edges, "count": count, "median": stats[0], "p25": stats[1], "p75": stats[2]}

