"""Lidar-motion instances lifted from their own points, not back through their masks.

The lidar-motion source (lidar_motion.py) knows each instance's lidar points: its clusters. Lifting
its masks back to lidar (lifting.py) loses some of them where the masks, drawn as hulls, overlap:
a car behind a pedestrian in one camera hands the pedestrian the points inside the pedestrian's
hull, and the mask erosion and the largest-cluster rule trim a partly seen car further. Here each
cluster becomes the instance's observation at its sweep's frame as it is; every point takes the
first image of that frame it lands in (its pixel is where registration reads colours and
features), and points no camera sees are dropped, as painting would drop them; each observation
records the share of its cluster that was kept (``seen_fraction``): a vehicle passing beside the
ego is cut by the cameras' field of view, and registration must not take the cut for its end.
The clusters whole, seen or not, are read from the same file by :func:`load_lidar_views` when
registration carries an instance on out of the cameras' view from its lidar alone (out_of_view.py).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Iterable

import numpy as np
from tqdm import tqdm

from idsplat_ns.data.rolling_shutter import camera_paths, project_rolling
from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.cache import load_npz
from idsplat_ns.instances.lifting import InstanceObservation, LiftedInstances, LiftingConfig, pixels_inside
from idsplat_ns.instances.masks.lidar_motion import TRACK_POINTS


def _read_track_points(mask_dir: Path) -> tuple[dict, dict]:
    """The arrays and index of ``mask_dir``'s :data:`TRACK_POINTS` (one line naming it if missing)."""
    path = Path(mask_dir) / TRACK_POINTS
    if not path.is_file():
        raise IDSplatError(f"{path}: missing; delete {mask_dir} so that the lidar-motion masks are made again")
    return load_npz(path)


def lift_track_points(scene: Scene, mask_dir: Path, labels: dict[int, str], config: LiftingConfig,
                      progress: bool = True) -> LiftedInstances:
    """:class:`LiftedInstances` of the tracks stored in ``mask_dir`` by :func:`~idsplat_ns.instances.masks.lidar_motion.save_track_points`."""
    data, index = _read_track_points(mask_dir)
    position = {int(f): k for k, f in enumerate(scene.frame_indices)}
    # Each image belongs to the frame of its closest sweep, as in painting.
    images_of_frame: dict[int, list[int]] = defaultdict(list)
    for i, image in enumerate(scene.images):
        sweep = scene.closest_sweep(image.time)
        if sweep is not None:
            images_of_frame[int(sweep.frame_index)].append(i)
    paths = camera_paths(scene.images) if config.rolling_shutter else {}
    observations: dict[int, list[InstanceObservation]] = {}
    for key, frames in tqdm(index.items(), desc="lidar motion: lifting", disable=not progress):
        tid = int(key)
        obs = []
        for f in frames:
            if f not in position:
                continue
            pts, times = data[f"{tid}_{f}_points"], data[f"{tid}_{f}_times"]
            image_ids = np.full(len(pts), -1, np.int32)
            uv = np.zeros((len(pts), 2), np.float32)
            for i in images_of_frame.get(f, []):
                image = scene.images[i]
                proj, _ = project_rolling(pts, image, paths.get(image.camera))
                take = proj.valid & (image_ids < 0)
                image_ids[take] = i
                uv[take] = pixels_inside(proj.uv[take], image)
            seen = image_ids >= 0
            if seen.sum() >= config.min_points:
                obs.append(InstanceObservation(position[f], pts[seen], image_ids[seen], uv[seen], times[seen].astype(np.float64),
                                               seen_fraction=float(seen.mean())))
        if obs:
            observations[tid] = sorted(obs, key=lambda o: o.frame)
    return LiftedInstances({k: labels.get(k, "object") for k in observations}, observations)


def load_lidar_views(scene: Scene, mask_dir: Path, instance_ids: Iterable[int],
                     min_points: int) -> dict[int, dict[int, np.ndarray]]:
    """Per instance of ``instance_ids``, frame (position in ``scene.frame_indices``) -> [N, 3]
    world points: every cluster of at least ``min_points`` returns that ``mask_dir``'s
    :data:`TRACK_POINTS` holds, whether a camera saw it or not."""
    data, index = _read_track_points(mask_dir)
    position = {int(f): k for k, f in enumerate(scene.frame_indices)}
    wanted = {int(i) for i in instance_ids}
    views: dict[int, dict[int, np.ndarray]] = {}
    for key, frames in index.items():
        if int(key) not in wanted:
            continue
        for f in frames:
            pts = data[f"{key}_{f}_points"]
            if f in position and len(pts) >= min_points:
                views.setdefault(int(key), {})[position[f]] = np.asarray(pts, np.float64)
    return views
