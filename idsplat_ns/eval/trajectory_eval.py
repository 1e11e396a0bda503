"""Tracking evaluation of instance trajectories against ground-truth tracks (supplementary
"Tracking results"): positions per frame -> CLEAR-MOT at the paper's distance thresholds.

Two protocols. *Observed* (the headline): a ground-truth object counts at a frame only where the
method could have seen it: its box appears in a camera image of that frame, lies within the lidar
range the instances are lifted from (80 m) and holds at least 10 lidar points (the paper's filter
for its dynamic-region masks). *All*: every annotated moving object of the evaluated classes at
every frame, whether any sensor of the method saw it or not.

Classes. An evaluation covers a set of classes (:data:`ROAD_USER_CLASSES`): the headline is the
moving vehicles, as the paper; beside it each class alone and all moving road users together.
Predictions carry no class here: a prediction left unmatched inside the box (grown by
``dont_care_margin``) of an object that does not count is neither a match nor a false positive (a
"don't care" region, as in KITTI). Objects that do not count are the unobserved ones of the
evaluated classes and every annotated road user (moving or not) of the other classes, so that a
tracked pedestrian is no false positive of the vehicle evaluation. Parked vehicles and standing
people of an evaluated class do count against predictions on them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from idsplat_ns.data.dynamic_masks import box_silhouette
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import ObjectTrack, ROAD_USER_CLASSES, points_in_box
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
    """Metres: predictions left unmatched inside the box, grown by this, of an object that does not
    count (unobserved, or a road user of another class) are not false positives."""


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
    """``{frame: {track_id: xyz}}`` of the annotated (moving) objects of the class ``groups``, box
    centres in the world; with ``observed``, only where the filter counts them."""
    return _ground_truth(scene, scene_annotations(scene, observed, moving_only), groups, moving_only)[0]


@dataclass(frozen=True)
class Annotation:
    """One annotated box at one frame, with whether the observed filter counts it."""

    frame: int
    track: ObjectTrack
    pose: np.ndarray  # [4, 4] box-to-world
    observed: bool


def scene_annotations(scene: Scene, observed: Optional[ObservedFilter], moving_only: bool = True) -> list[Annotation]:
    """Every road user's box at every scene frame, with the observed filter evaluated once (with
    ``moving_only``, for the moving ones only: only those can count)."""
    frames = {int(f) for f in scene.frame_indices}
    index = _FrameIndex(scene, observed.max_range) if observed is not None else None
    out = []
    for track in scene.tracks:
        if track.group not in ROAD_USER_CLASSES:
            continue
        for k, (f, pose) in enumerate(zip(track.frame_indices, track.poses)):
            if int(f) not in frames:
                continue
            seen = observed is None or ((track.moving or not moving_only) and _observed(index, track, k, int(f), observed))
            out.append(Annotation(int(f), track, pose, seen))
    return out


def _ground_truth(scene: Scene, annotations: list[Annotation], groups: Sequence[str], moving_only: bool):
    """Counted positions ``{frame: {id: xyz}}`` (every scene frame) and boxes that do not count
    ``{frame: [(pose, size)]}``: unobserved objects of ``groups`` and every road user of the other
    classes."""
    frames: dict = {int(f): {} for f in scene.frame_indices}
    ignored: dict = {}
    for a in annotations:
        counted = frames[a.frame]
        if a.track.group in groups:
            if moving_only and not a.track.moving:
                continue  # a parked car of an evaluated class: a prediction on it is a false positive
            if a.observed:
                counted[a.track.track_id] = a.pose[:3, 3].copy()
                continue
        ignored.setdefault(a.frame, []).append((a.pose, a.track.size))
    return frames, ignored


def _dont_care(pred: dict, ignored: dict, margin: float) -> dict:
    """``{frame: {prediction id}}`` of the predictions inside a box that does not count (grown by ``margin``)."""
    out = {}
    for f, objects in pred.items():
        boxes = ignored.get(f, [])
        out[f] = {
            k for k, xyz in objects.items()
            if any(points_in_box(np.asarray(xyz, np.float64)[None], pose, size, margin)[0] for pose, size in boxes)
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
    groups: Sequence[str] = ("vehicle",),
) -> dict[float, TrackingMetrics]:
    """CLEAR-MOT of the predicted instance positions against the GT centres of the moving objects
    of the classes ``groups`` (default: the paper's vehicles), under the observed protocol
    (default) or, with ``observed=None``, against all of them."""
    return class_tracking_summaries(scene, positions_at, {"_": tuple(groups)}, thresholds, observed, keep_absent=True)["_"]


TRACKING_CLASS_SETS: dict[str, tuple[str, ...]] = {
    "vehicle": ("vehicle",),
    "pedestrian": ("pedestrian",),
    "cyclist": ("cyclist",),
    "road_users": ROAD_USER_CLASSES,
}
"""The evaluations of :func:`class_tracking_summaries`: each class alone, and all road users."""


def class_tracking_summaries(
    scene: Scene,
    positions_at: Callable[[float], dict],
    class_sets: dict[str, Sequence[str]] = TRACKING_CLASS_SETS,
    thresholds: Sequence[float] = PAPER_THRESHOLDS,
    observed: Optional[ObservedFilter] = ObservedFilter(),
    keep_absent: bool = False,
) -> dict[str, dict[float, TrackingMetrics]]:
    """:func:`tracking_summary` for several class sets ``{name: classes}`` at once (the observed
    filter and the predictions are evaluated once). A set without annotated moving objects in the
    scene is left out of the result unless ``keep_absent``."""
    annotations = scene_annotations(scene, observed)
    margin = (observed or ObservedFilter()).dont_care_margin
    pred = predicted_positions(scene, positions_at)
    out = {}
    for name, groups in class_sets.items():
        if not keep_absent and not any(t.moving and t.group in groups for t in scene.tracks):
            continue
        gt, ignored = _ground_truth(scene, annotations, tuple(groups), True)
        out[name] = clear_mot(gt, pred, thresholds, dont_care=_dont_care(pred, ignored, margin))
    return out


def flatten_metrics(
    results: dict[float, TrackingMetrics], thresholds: Sequence[float] = PAPER_THRESHOLDS, prefix: str = ""
) -> dict[str, float]:
    """Flat ``{"mota@2m": ..., "motp@2m": ..., "idf1@2m": ..., ...}`` for logs and JSON at each of
    ``thresholds`` (default: the paper's six; each key preceded by ``prefix``, e.g. ``pedestrian_``);
    empty where no object counted (a class the data does not show has no metrics, not zeros). MOTP
    is absent without matches."""
    out: dict[str, float] = {}
    for th in thresholds:
        m = results.get(th)
        if m is None or m.num_objects == 0:
            continue
        tag = f"@{th:g}m"
        out[prefix + "mota" + tag] = float(m.mota)
        if m.num_detections:
            out[prefix + "motp" + tag] = float(m.motp)
        out[prefix + "recall" + tag] = float(m.recall)
        if m.num_predictions:
            out[prefix + "precision" + tag] = float(m.precision)
        out[prefix + "objects" + tag] = float(m.num_objects)
        out[prefix + "matches" + tag] = float(m.num_matches)
        out[prefix + "false_positives" + tag] = float(m.num_false_positives)
        out[prefix + "misses" + tag] = float(m.num_misses)
        out[prefix + "id_switches" + tag] = float(m.num_switches)
        out[prefix + "fragmentations" + tag] = float(m.num_fragmentations)
        out[prefix + "idf1" + tag] = float(m.idf1)
    return out


def tracking_metrics(scene: Scene, positions_at: Callable[[float], dict]) -> dict[str, float]:
    """What ns-eval reports: the observed protocol for the moving vehicles (no prefix, the paper's
    headline), each other class (``pedestrian_``, ``cyclist_``; ``vehicle`` is the headline) and all
    moving road users (``road_users_``), and the all-objects protocol for the vehicles (``all_``).
    Classes the scene does not annotate as moving are absent."""
    observed = class_tracking_summaries(scene, positions_at)
    out: dict[str, float] = {}
    for name, results in observed.items():
        out.update(flatten_metrics(results, prefix="" if name == "vehicle" else f"{name}_"))
    if "vehicle" in observed:
        out.update(flatten_metrics(tracking_summary(scene, positions_at, observed=None), prefix="all_"))
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
