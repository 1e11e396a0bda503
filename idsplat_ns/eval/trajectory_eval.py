"""Tracking evaluation of instance trajectories against ground-truth tracks (supplementary
"Tracking results"): positions per frame -> CLEAR-MOT at the paper's distance thresholds.

Two protocols. *Observed* (the headline): a ground-truth object counts at a frame only where the
method could have seen it: its box appears in a camera image of that frame, lies within the lidar
range the instances are lifted from (80 m) and holds at least 10 lidar points (the paper's filter
for its dynamic-region masks). A prediction inside an object that does not count there is neither
a match nor a false positive (a "don't care" region, as in KITTI). *All*: every annotated moving
vehicle at every frame, whether any sensor of the method saw it or not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import ObjectTrack, points_in_box
from idsplat_ns.eval.tracking import PAPER_THRESHOLDS, TrackingMetrics, clear_mot


@dataclass(frozen=True)
class ObservedFilter:
    """Which annotated objects count, per frame, under the *observed* protocol."""

    max_range: float = 80.0
    """Metres from the lidar: the range instance lifting uses (paper, supplementary)."""
    min_lidar_points: int = 10
    """Returned lidar points inside the box (within ``max_range``), the paper's mask filter."""
    require_camera: bool = True
    """The box must project into at least one camera image of the frame."""
    dont_care_margin: float = 1.0
    """Metres: predictions within an uncounted object's box grown by this are ignored."""


class _FrameIndex:
    """A scene's images and lidar sweep per frame, and each sweep's points within range, built
    once for all the (track, frame) pairs the observed filter checks."""

    def __init__(self, scene: Scene, max_range: float) -> None:
        self.images: dict[int, list] = {}
        for image in scene.images:
            self.images.setdefault(int(image.frame_index), []).append(image)
        self.sweeps: dict[int, object] = {}
        for sweep in scene.lidar:
            self.sweeps.setdefault(int(sweep.frame_index), sweep)
        self.max_range = max_range
        self._near_points: dict[int, np.ndarray] = {}

    def points_in_range(self, frame: int) -> np.ndarray:  # -> [M, 3] returned points within max_range
        if frame not in self._near_points:
            sweep = self.sweeps[frame]
            self._near_points[frame] = sweep.points[sweep.ranges[sweep.returned] <= self.max_range]
        return self._near_points[frame]


def _in_some_image(index: _FrameIndex, frame: int, pose: np.ndarray, size: np.ndarray) -> bool:
    """Whether the box's silhouette overlaps any image of ``frame`` (occlusion not modelled)."""
    import cv2

    from idsplat_ns.data.dynamic_masks import box_silhouette

    for image in index.images.get(frame, []):
        poly = box_silhouette(image, pose, size)
        if poly is None or len(poly) < 3:
            continue
        w, h = image.intrinsics.width, image.intrinsics.height
        rect = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float32)
        area, _ = cv2.intersectConvexConvex(poly.astype(np.float32), rect)
        if area > 0:
            return True
    return False


def _observed(index: _FrameIndex, track: ObjectTrack, k: int, frame: int, config: ObservedFilter) -> bool:
    pose, size = track.poses[k], track.size
    sweep = index.sweeps.get(frame)
    if sweep is not None:
        if np.linalg.norm(pose[:3, 3] - sweep.sensor_to_world[:3, 3]) > config.max_range:
            return False
        if config.min_lidar_points > 0 and track.num_lidar_points is not None:  # the dataset's own count
            if track.num_lidar_points[k] < config.min_lidar_points:
                return False
        elif config.min_lidar_points > 0:
            if points_in_box(index.points_in_range(frame), pose, size).sum() < config.min_lidar_points:
                return False
    return not config.require_camera or _in_some_image(index, frame, pose, size)


def ground_truth_positions(
    scene: Scene,
    groups: Sequence[str] = ("vehicle",),
    moving_only: bool = True,
    observed: Optional[ObservedFilter] = None,
) -> dict:
    """``{frame: {track_id: xyz}}`` of the annotated (moving) objects, box centres in the world;
    with ``observed``, only where the filter counts them."""
    return _ground_truth(scene, groups, moving_only, observed)[0]


def _ground_truth(scene: Scene, groups: Sequence[str], moving_only: bool, observed: Optional[ObservedFilter]):
    """Counted positions ``{frame: {id: xyz}}`` and uncounted boxes ``{frame: [(pose, size)]}``."""
    frames: dict = {int(f): {} for f in scene.frame_indices}
    ignored: dict = {int(f): [] for f in scene.frame_indices}
    index = _FrameIndex(scene, observed.max_range) if observed is not None else None
    for track in scene.tracks:
        if track.group not in groups or (moving_only and not track.moving):
            continue
        for k, (f, pose) in enumerate(zip(track.frame_indices, track.poses)):
            f = int(f)
            if f not in frames:
                continue
            if observed is None or _observed(index, track, k, f, observed):
                frames[f][track.track_id] = pose[:3, 3].copy()
            else:
                ignored[f].append((pose, track.size))
    return frames, ignored


def _drop_dont_care(pred: dict, ignored: dict, margin: float) -> dict:
    """Predictions outside every uncounted box (grown by ``margin``)."""
    out = {}
    for f, objects in pred.items():
        boxes = ignored.get(f, [])
        out[f] = {
            k: xyz for k, xyz in objects.items()
            if not any(points_in_box(np.asarray(xyz, np.float64)[None], pose, size, margin)[0] for pose, size in boxes)
        }
    return out


def predicted_positions(scene: Scene, positions_at: Callable[[float], dict]) -> dict:
    """``{frame: {instance_id: xyz}}`` from a function of time (seconds) -> present instances' origins."""
    return {int(f): positions_at(float(t)) for f, t in zip(scene.frame_indices, scene.frame_times)}


def tracking_summary(
    scene: Scene,
    positions_at: Callable[[float], dict],
    thresholds: Sequence[float] = PAPER_THRESHOLDS,
    observed: Optional[ObservedFilter] = ObservedFilter(),
) -> dict[float, TrackingMetrics]:
    """CLEAR-MOT of the predicted instance positions against the moving vehicles' GT centres,
    under the observed protocol (default) or, with ``observed=None``, against all of them."""
    gt, ignored = _ground_truth(scene, ("vehicle",), True, observed)
    pred = predicted_positions(scene, positions_at)
    if observed is not None:
        pred = _drop_dont_care(pred, ignored, observed.dont_care_margin)
    return clear_mot(gt, pred, thresholds)


def flatten_metrics(
    results: dict[float, TrackingMetrics], thresholds: Sequence[float] = (1.0, 2.0, 5.0), prefix: str = ""
) -> dict[str, float]:
    """Flat ``{"mota@2m": ..., "motp@2m": ..., "recall@2m": ..., ...}`` for logs and JSON
    (each key preceded by ``prefix``, e.g. ``all_``)."""
    out: dict[str, float] = {}
    for th in thresholds:
        if th in results:
            m = results[th]
            tag = f"@{th:g}m"
            out[prefix + "mota" + tag] = float(m.mota)
            out[prefix + "motp" + tag] = float(m.motp) if np.isfinite(m.motp) else float("nan")
            out[prefix + "recall" + tag] = float(m.recall)
            out[prefix + "precision" + tag] = float(m.precision)
            out[prefix + "id_switches" + tag] = float(m.num_switches)
            out[prefix + "objects" + tag] = float(m.num_objects)
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
