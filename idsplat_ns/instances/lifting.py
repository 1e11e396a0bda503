"""Lifting 2D instance masks to lidar points (paper Sec. 3.2, supplementary "Instance decomposition").

For every image, the temporally closest lidar sweep is projected with the full camera model; points
within ``max_distance`` of the sensor that land inside an (eroded) instance mask take its ID. Per
instance and frame, the points from all cameras are merged and clustered with DBSCAN, and only the
largest cluster is kept. Instance IDs that come from different cameras (per-camera tracking) are
merged when they claim the same lidar points at the same frame and never meet in one image.

Rolling-shutter images (Waymo; the built-in street made with ``--rolling-shutter-ms``): each
point is projected with the camera pose of the line it lands on. That pose is interpolated along
the camera's own path, and the line's time is solved by
:func:`~idsplat_ns.data.rolling_shutter.project_rolling`. Each point keeps its own lidar time
(``InstanceObservation.times``) and its world position at that time. A moving object's motion
between its lidar time and the line's time is not compensated: it is not known before
registration.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
from sklearn.cluster import DBSCAN
from tqdm import tqdm

from idsplat_ns.data.rolling_shutter import camera_paths, project_rolling
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.cache import load_npz, save_npz
from idsplat_ns.instances.masks.base import InstanceMaskSet
from idsplat_ns.ranges import POSITIVE, UNIT, bounded


@dataclass(frozen=True)
class LiftingConfig:
    """Mask-to-lidar settings; defaults are the paper's."""

    erosion_px: int = 3
    """Each instance mask is eroded by this many pixels before projection (0 disables: ablation a)."""
    min_kept_area: float = bounded(0.5, UNIT)
    """Ours, not the paper's: a mask is eroded by the largest radius up to ``erosion_px`` that keeps at
    least this fraction of its pixels, so a far object a few pixels tall is trimmed less or not at all
    instead of vanishing (its mounting-offset parallax is small anyway). 0 erodes every mask by
    ``erosion_px``, as the paper does."""
    max_distance: float = 80.0
    """Metres: lidar points farther from the sensor are ignored."""
    use_dbscan: bool = True
    """Keep only the largest DBSCAN cluster of each instance and frame (False: ablation b)."""
    dbscan_eps: float = bounded(0.5, POSITIVE)
    """DBSCAN neighbourhood radius in metres."""
    dbscan_min_samples: int = 10
    """DBSCAN minimum neighbours of a core point."""
    min_points: int = 10
    """Observations (instance at one frame) with fewer points are dropped."""
    merge_overlap: float = bounded(0.3, UNIT)
    """Two IDs are one object when, at one frame, this fraction of the smaller one's points are shared."""
    rolling_shutter: bool = True
    """Project into rolling-shutter images with each line's camera pose (no effect on global-shutter
    images; False: the ablation, every point with the image's single pose)."""


@dataclass
class InstanceObservation:
    """The lidar points of one instance at one frame."""

    frame: int
    """Position in ``scene.frame_indices`` (0..F-1)."""
    points: np.ndarray
    """[N, 3] float64 world points."""
    image_ids: np.ndarray
    """[N] int32 index into ``scene.images`` of the image the point was painted from."""
    uv: np.ndarray
    """[N, 2] float32 pixel coordinates of the point in that image."""
    times: Optional[np.ndarray] = None
    """[N] float64 seconds: when the lidar ray of each point was fired (a sweep takes 0.1 s, in
    which a car at 12 m/s moves 1.2 m). None where unknown: the frame's time is used."""
    seen_fraction: Optional[float] = None
    """Share of the instance's lidar points at this frame that a camera sees (the rest are not
    kept: they have no pixel). Known where the lidar gave the whole instance (lidar-motion
    lifting); None where only the camera's part is known."""


@dataclass
class LiftedInstances:
    """Per instance ID, its class and its observations (sorted by frame)."""

    labels: dict[int, str]
    """Class of each instance ID."""
    observations: dict[int, list[InstanceObservation]]
    """Observations per instance ID."""

    def save(self, path: Path) -> None:
        arrays: dict[str, np.ndarray] = {}
        index = {}
        for iid, obs_list in self.observations.items():
            index[str(iid)] = {"label": self.labels[iid], "frames": [o.frame for o in obs_list]}
            for o in obs_list:
                arrays[f"{iid}_{o.frame}_points"] = o.points
                arrays[f"{iid}_{o.frame}_image_ids"] = o.image_ids
                arrays[f"{iid}_{o.frame}_uv"] = o.uv
                if o.times is not None:
                    arrays[f"{iid}_{o.frame}_times"] = o.times
                if o.seen_fraction is not None:
                    arrays[f"{iid}_{o.frame}_seen_fraction"] = np.float64(o.seen_fraction)
        save_npz(path, arrays, index)

    @classmethod
    def load(cls, path: Path) -> "LiftedInstances":
        data, index = load_npz(path)
        labels, observations = {}, {}
        for key, entry in index.items():
            iid = int(key)
            labels[iid] = entry["label"]
            observations[iid] = [
                InstanceObservation(f, data[f"{iid}_{f}_points"], data[f"{iid}_{f}_image_ids"], data[f"{iid}_{f}_uv"],
                                    data.get(f"{iid}_{f}_times"), _optional_float(data.get(f"{iid}_{f}_seen_fraction")))
                for f in entry["frames"]
            ]
        return cls(labels, observations)


def _optional_float(value) -> Optional[float]:
    return None if value is None else float(value)


def erode_instance_map(ids: np.ndarray, radius: int) -> np.ndarray:  # ids: [H, W] uint16
    """Shrink every instance by ``radius`` pixels: a pixel keeps its ID only when every pixel of the
    disk around it has the same ID (so borders between two instances are eroded too)."""
    if radius <= 0:
        return ids
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    lo = cv2.erode(ids, kernel, borderType=cv2.BORDER_REPLICATE)
    hi = cv2.dilate(ids, kernel, borderType=cv2.BORDER_REPLICATE)
    return np.where((lo == ids) & (hi == ids), ids, 0).astype(ids.dtype)


def erode_instance_map_adaptive(ids: np.ndarray, radius: int, min_kept_area: float) -> np.ndarray:  # [H, W]
    """Like :func:`erode_instance_map`, but each instance takes the largest radius <= ``radius`` that
    keeps at least ``min_kept_area`` of its pixels (radius 0 when even one pixel of erosion would
    remove more)."""
    if radius <= 0 or min_kept_area <= 0:
        return erode_instance_map(ids, radius)
    area = np.bincount(ids.ravel().astype(np.int64))
    out = np.zeros_like(ids)
    decided = np.zeros(len(area), bool)
    decided[0] = True
    for r in range(radius, -1, -1):
        eroded = erode_instance_map(ids, r)
        kept = np.bincount(eroded.ravel().astype(np.int64), minlength=len(area))
        take = ~decided & ((kept >= min_kept_area * area) | (r == 0)) & (area > 0)
        if take.any():
            sel = take[eroded]
            out[sel] = eroded[sel]
            decided |= take
        if decided[area > 0].all():
            break
    return out


def largest_cluster(points: np.ndarray, eps: float, min_samples: int) -> np.ndarray:  # points: [N, 3]
    """[N] bool: members of the largest DBSCAN cluster (all false when there is no cluster)."""
    if len(points) < min_samples:
        return np.zeros(len(points), bool)
    labels = DBSCAN(eps=eps, min_samples=min_samples).fit(points).labels_
    if labels.max() < 0:
        return np.zeros(len(points), bool)
    return labels == np.argmax(np.bincount(labels[labels >= 0]))


class _UnionFind:
    def __init__(self) -> None:
        self.parent: dict[int, int] = {}

    def find(self, a: int) -> int:
        self.parent.setdefault(a, a)
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def union(self, a: int, b: int) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[max(ra, rb)] = min(ra, rb)  # the smaller ID survives


def pixels_inside(uv: np.ndarray, image) -> np.ndarray:  # uv: [N, 2] -> [N, 2] float32
    """Pixel coordinates of points inside ``image`` as float32, kept inside: float32 can round a
    coordinate just inside the image up onto its edge."""
    edge = np.nextafter(np.array([image.intrinsics.width, image.intrinsics.height], np.float32), np.float32(0))
    return np.minimum(np.asarray(uv).astype(np.float32), edge)


def paint_points(scene: Scene, masks: InstanceMaskSet, config: LiftingConfig, progress: bool = True):
    """Per frame and instance ID, the lidar point indices (into that frame's returned points) and the
    image index and pixel each was painted from; also the set of IDs seen in each image."""
    frame_of_index = {int(f): k for k, f in enumerate(scene.frame_indices)}
    painted: dict[int, dict[int, list[tuple[np.ndarray, int, np.ndarray]]]] = defaultdict(lambda: defaultdict(list))
    co_visible: list[set[int]] = []
    sweep_cache: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
    paths = camera_paths(scene.images) if config.rolling_shutter else {}
    for img_idx, image in enumerate(tqdm(scene.images, desc="point painting", disable=not progress)):
        ids = masks.load(image.camera, image.frame_index)
        if ids is None or not ids.any():
            continue
        sweep = scene.closest_sweep(image.time)
        if sweep is None:
            continue
        frame = frame_of_index.get(int(sweep.frame_index))
        if frame is None:
            continue
        if id(sweep) not in sweep_cache:
            ranges = sweep.ranges[sweep.returned]
            sweep_cache[id(sweep)] = (frame, sweep.points, ranges <= config.max_distance, sweep.times[sweep.returned])
        frame, points, near, _ = sweep_cache[id(sweep)]
        eroded = erode_instance_map_adaptive(ids, config.erosion_px, config.min_kept_area)
        proj, _ = project_rolling(points, image, paths.get(image.camera))
        ok = proj.valid & near
        idx = np.nonzero(ok)[0]
        # Masks may be stored at another resolution than the intrinsics: scale pixel coordinates.
        sx, sy = ids.shape[1] / image.intrinsics.width, ids.shape[0] / image.intrinsics.height
        col = np.clip((proj.uv[idx, 0] * sx).astype(np.int64), 0, ids.shape[1] - 1)
        row = np.clip((proj.uv[idx, 1] * sy).astype(np.int64), 0, ids.shape[0] - 1)
        hit = eroded[row, col]
        co_visible.append(set(np.unique(ids[ids > 0]).tolist()))
        for k in np.unique(hit[hit > 0]):
            sel = hit == k
            painted[frame][int(k)].append((idx[sel], img_idx, pixels_inside(proj.uv[idx[sel]], image)))
    return painted, co_visible, sweep_cache


def lift_instances(scene: Scene, masks: InstanceMaskSet, config: LiftingConfig = LiftingConfig(), progress: bool = True) -> LiftedInstances:
    """Lidar points of every instance at every frame where it is masked."""
    painted, co_visible, sweep_cache = paint_points(scene, masks, config, progress)
    points_of_frame = {frame: pts for frame, pts, _, _ in sweep_cache.values()}
    times_of_frame = {frame: t for frame, _, _, t in sweep_cache.values()}

    # Merge IDs that claim the same lidar points at one frame but never share an image.
    together = {(a, b) for s in co_visible for a in s for b in s if a < b}
    uf = _UnionFind()
    for frame, per_id in painted.items():
        sets = {k: np.unique(np.concatenate([p[0] for p in v])) for k, v in per_id.items()}
        keys = sorted(sets)
        for i, a in enumerate(keys):
            for b in keys[i + 1 :]:
                if (a, b) in together:
                    continue
                shared = len(np.intersect1d(sets[a], sets[b], assume_unique=True))
                if shared >= config.merge_overlap * min(len(sets[a]), len(sets[b])) and shared > 0:
                    uf.union(a, b)

    labels: dict[int, str] = {}
    observations: dict[int, list[InstanceObservation]] = defaultdict(list)
    for frame in sorted(painted):
        merged: dict[int, list] = defaultdict(list)
        for k, parts in painted[frame].items():
            merged[uf.find(k)].extend(parts)
        for root, parts in merged.items():
            idx = np.concatenate([p[0] for p in parts])
            img = np.concatenate([np.full(len(p[0]), p[1], np.int32) for p in parts])
            uv = np.concatenate([p[2] for p in parts])
            idx, first = np.unique(idx, return_index=True)  # a point seen by two cameras counts once
            img, uv = img[first], uv[first]
            pts, ray_times = points_of_frame[frame][idx], times_of_frame[frame][idx]
            if config.use_dbscan:
                keep = largest_cluster(pts, config.dbscan_eps, config.dbscan_min_samples)
                pts, img, uv, ray_times = pts[keep], img[keep], uv[keep], ray_times[keep]
            if len(pts) < config.min_points:
                continue
            observations[root].append(InstanceObservation(frame, pts, img, uv, ray_times.astype(np.float64)))
    for k in list(observations):
        members = [m for m in masks.labels if uf.find(m) == k] or [k]
        votes = Counter(masks.labels.get(m, "object") for m in members)
        labels[k] = votes.most_common(1)[0][0]
    return LiftedInstances(labels, dict(observations))
