"""Ground-truth dynamic-region masks (for DPSNR): pixels of moving objects in an image.

Where the dataset has instance masks (the synthetic street), they are used directly. Otherwise the
moving objects' 3D boxes are projected and their silhouettes (convex hull of the projected
corners) filled, as the paper's protocol does for Waymo. Evaluation only.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.images import load_instance_mask
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import box_corners, label_group


def dynamic_mask(
    scene: Scene,
    image: CameraImage,
    scale: float = 1.0,
    groups: Sequence[str] = ("vehicle",),
    min_lidar_points: Optional[int] = None,
) -> np.ndarray:
    """[H, W] bool mask of moving objects of the given class ``groups`` in ``image`` at ``scale``.

    ``min_lidar_points`` drops boxes with fewer lidar points (the paper uses 10) where tracks
    carry point counts.
    """
    intr = image.intrinsics.scaled(scale)
    instance_map = load_instance_mask(image, scale)
    classes = scene.metadata.get("gt_instances")
    if instance_map is not None and classes is not None:
        moving_ids = [k for k, v in classes.items() if v.get("moving") and label_group(v.get("label", "")) in groups]
        return np.isin(instance_map, moving_ids)
    mask = np.zeros((intr.height, intr.width), np.uint8)
    for track in scene.tracks:
        if not track.moving or track.group not in groups:
            continue
        hit = np.nonzero(track.frame_indices == image.frame_index)[0]
        if len(hit) == 0:
            continue
        k = hit[0]
        if min_lidar_points is not None and track.num_lidar_points is not None and track.num_lidar_points[k] < min_lidar_points:
            continue
        _fill_box(mask, box_corners(track.poses[k], track.size), image.camera_to_world, intr)
    return mask.astype(bool)


def _fill_box(mask: np.ndarray, corners: np.ndarray, camera_to_world: np.ndarray, intr) -> None:
    import cv2

    from idsplat_ns.data.camera import project_points

    proj = project_points(corners, camera_to_world, intr, min_depth=0.1)
    in_front = proj.depth > 0.1
    if in_front.sum() < 3:
        return
    if not np.all(in_front):
        # Clip the box to the near plane by keeping its in-front corners plus the points where
        # its edges cross the plane, so partly visible boxes still cover the right pixels.
        corners = _clip_box_to_near_plane(corners, camera_to_world, 0.1)
        proj = project_points(corners, camera_to_world, intr, min_depth=0.05)
    hull = cv2.convexHull(np.round(proj.uv).astype(np.int32).clip(-10**6, 10**6))
    cv2.fillConvexPoly(mask, hull, 1)


def _clip_box_to_near_plane(corners: np.ndarray, camera_to_world: np.ndarray, near: float) -> np.ndarray:
    R, t = camera_to_world[:3, :3], camera_to_world[:3, 3]
    cam = (corners - t) @ R
    z = cam[:, 2]
    keep = [corners[i] for i in range(8) if z[i] > near]
    for i in range(8):
        for j in range(i + 1, 8):
            if bin(i ^ j).count("1") != 1:  # box edges join corners differing in one sign
                continue
            if (z[i] > near) != (z[j] > near):
                s = (near - z[i]) / (z[j] - z[i])
                keep.append(corners[i] + s * (corners[j] - corners[i]))
    return np.asarray(keep)
