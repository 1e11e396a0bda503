"""The ``lidar-motion`` mask source: instance masks drawn from the moving lidar tracks of
:mod:`idsplat_ns.instances.lidar_motion` (no model files, no annotations), with the tracks' own
points written beside them as the lifted observations."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.lidar_motion import motion_sweeps, moving_tracks
from idsplat_ns.instances.cache import save_npz
from idsplat_ns.instances.masks.base import InstanceMaskSet, MaskSource, mask_filename, write_instance_map, write_labels
from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack


TRACK_POINTS = "track_points.npz"
"""File in a lidar-motion mask folder with each track's cluster points per sweep."""


def save_track_points(out_dir: Path, tracks: list[MotionTrack], sweep_frame_indices: list[int]) -> None:
    """Write the clusters of ``tracks`` to ``out_dir/TRACK_POINTS``;
    ``sweep_frame_indices[k]`` is the dataset frame index of the k-th sweep the clusters count."""
    arrays, index = {}, {}
    for tr in tracks:
        frames = []
        for c in tr.clusters:
            f = int(sweep_frame_indices[c.frame])
            arrays[f"{tr.track_id}_{f}_points"] = c.points
            arrays[f"{tr.track_id}_{f}_times"] = c.times
            frames.append(f)
        index[str(tr.track_id)] = frames
    save_npz(Path(out_dir) / TRACK_POINTS, arrays, index)


def render_track_masks(scene: Scene, tracks: list[MotionTrack], config: LidarMotionConfig, out_dir: Path,
                       progress: bool = False) -> None:
    """Write one instance map per image: each track's points at the image time, hull-filled."""
    sweep_frames = [s.frame_index for s in motion_sweeps(scene)]
    by_frame: dict[int, list[tuple[MotionTrack, MotionCluster]]] = {}
    for tr in tracks:
        for c in tr.clusters:
            by_frame.setdefault(sweep_frames[c.frame], []).append((tr, c))
    kernel = np.ones((2 * config.mask_dilation_px + 1,) * 2, np.uint8) if config.mask_dilation_px > 0 else None
    for image in tqdm(scene.images, desc="lidar motion: masks", unit="image", disable=not progress):
        K = image.intrinsics
        ids = np.zeros((K.height, K.width), np.uint16)
        items = []
        for tr, c in by_frame.get(image.frame_index, []):
            pts = c.points + tr.velocity[None] * (image.time - c.times)[:, None]  # to the image time
            proj = image.project(pts)
            if proj.valid.sum() >= 3:
                items.append((float(np.median(proj.depth[proj.valid])), tr.track_id, proj.uv[proj.valid]))
        for _, track_id, uv in sorted(items, key=lambda x: -x[0]):  # far to near: near objects win
            hull = cv2.convexHull(np.round(uv).astype(np.int32))
            layer = np.zeros_like(ids, np.uint8)
            cv2.fillConvexPoly(layer, hull, 1)
            if kernel is not None:
                layer = cv2.dilate(layer, kernel)
            ids[layer > 0] = track_id
        write_instance_map(out_dir / mask_filename(image.camera, image.frame_index), ids)


def _finite_or_none(value: float):
    """JSON has no NaN: None where a value is unknown."""
    return round(float(value), 3) if np.isfinite(value) else None


class LidarMotionMaskSource(MaskSource):
    """Instance masks from moving lidar clusters (no model files, no annotations)."""

    name = "lidar-motion"

    def __init__(self, config: LidarMotionConfig):
        self.config = config

    def cache_key(self) -> dict:
        # labels: the version of the class-guess rule (cached instances.json files carry its
        # labels; 3: tall vehicles seen end-on are buses; 4: so are tall person-sized footprints).
        return {"kind": self.name, "labels": 4, **asdict(self.config)}

    def generate(self, scene: Scene, out_dir: Path, progress: bool = True) -> InstanceMaskSet:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        tracks = moving_tracks(scene, self.config, progress)
        render_track_masks(scene, tracks, self.config, out_dir, progress)
        save_track_points(out_dir, tracks, [s.frame_index for s in motion_sweeps(scene)])
        labels = {tr.track_id: tr.label(self.config.long_vehicle_height) for tr in tracks}
        write_labels(out_dir, labels, {tr.track_id: {"frames": len(tr.clusters), "motion_score": tr.median_score(),
                                                      "speed": _finite_or_none(tr.mean_speed()),
                                                      "footprint": [_finite_or_none(v) for v in tr.footprint()]}
                                 for tr in tracks})
        return InstanceMaskSet(out_dir, labels, self.name)

