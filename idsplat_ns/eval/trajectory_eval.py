"""Tracking evaluation of instance trajectories against ground-truth tracks (supplementary
"Tracking results"): positions per frame -> CLEAR-MOT at the paper's distance thresholds."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from idsplat_ns.data.scene import Scene
from idsplat_ns.eval.tracking import PAPER_THRESHOLDS, TrackingMetrics, clear_mot


def ground_truth_positions(scene: Scene, groups: Sequence[str] = ("vehicle",), moving_only: bool = True) -> dict:
    """``{frame: {track_id: xyz}}`` of the annotated (moving) objects, box centres in the world."""
    frames: dict = {int(f): {} for f in scene.frame_indices}
    for track in scene.tracks:
        if track.group not in groups or (moving_only and not track.moving):
            continue
        for f, pose in zip(track.frame_indices, track.poses):
            if int(f) in frames:
                frames[int(f)][track.track_id] = pose[:3, 3].copy()
    return frames


def predicted_positions(scene: Scene, positions_at: Callable[[float], dict]) -> dict:
    """``{frame: {instance_id: xyz}}`` from a function of time (seconds) -> present instances' origins."""
    return {int(f): positions_at(float(t)) for f, t in zip(scene.frame_indices, scene.frame_times)}


def tracking_summary(
    scene: Scene, positions_at: Callable[[float], dict], thresholds: Sequence[float] = PAPER_THRESHOLDS
) -> dict[float, TrackingMetrics]:
    """CLEAR-MOT of the predicted instance positions against the moving vehicles' GT centres."""
    gt = ground_truth_positions(scene)
    pred = predicted_positions(scene, positions_at)
    return clear_mot(gt, pred, thresholds)


def flatten_metrics(results: dict[float, TrackingMetrics], thresholds: Sequence[float] = (1.0, 2.0, 5.0)) -> dict[str, float]:
    """Flat ``{"mota@2m": ..., "motp@2m": ..., "recall@2m": ..., ...}`` for logs and JSON."""
    out: dict[str, float] = {}
    for th in thresholds:
        if th in results:
            m = results[th]
            tag = f"@{th:g}m"
            out["mota" + tag] = float(m.mota)
            out["motp" + tag] = float(m.motp) if np.isfinite(m.motp) else float("nan")
            out["recall" + tag] = float(m.recall)
            out["precision" + tag] = float(m.precision)
            out["id_switches" + tag] = float(m.num_switches)
    return out


def aligned_position_rmse(
    poses: np.ndarray,  # [T, 4, 4] instance canonical -> world
    gt_centres: np.ndarray,  # [T, 3] the matched object's box centres
) -> float:
    """Position RMSE after the best constant offset in the canonical frame.

    An instance's canonical origin is the centre of its densest lidar view, not the box centre,
    but for a rigid body the box centre is a fixed point ``c`` of the canonical frame. With
    ``R^T R = I`` the least-squares ``c`` is ``mean_t R_t^T (g_t - t_t)``; what remains measures
    the trajectory itself.
    """
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    c = np.mean(np.einsum("tji,tj->ti", R, gt_centres - t), axis=0)
    residual = np.einsum("tij,j->ti", R, c) + t - gt_centres
    return float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
