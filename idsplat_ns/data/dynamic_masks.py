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


def _at_scale(image: CameraImage, intr) -> CameraImage:
    from dataclasses import replace

    return image if intr == image.intrinsics else replace(image, intrinsics=intr)


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
    import cv2

    mask = np.zeros((intr.height, intr.width), np.uint8)
    for track in scene.tracks:
        if not track.moving or track.group not in groups:
            continue
        k = track.index_of_frame(image.frame_index)
        if k is None:
            continue
        if min_lidar_points is not None and track.num_lidar_points is not None and track.num_lidar_points[k] < min_lidar_points:
            continue
        poly = box_silhouette(_at_scale(image, intr), track.poses[k], track.size)
        if poly is not None and len(poly) >= 3:
            cv2.fillConvexPoly(mask, poly, 1)
    return mask.astype(bool)


_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]  # 12 box edges


def box_silhouette(image: CameraImage, pose: np.ndarray, size: np.ndarray, near: float = 0.1) -> Optional[np.ndarray]:
    """Pixel polygon [K, 2] int32 (convex hull) of a box (pose [4, 4] box-to-world, size [3]) in an
    image, or None when it is entirely behind the camera's ``near`` plane.

    Parts nearer than ``near`` are clipped away (the crossing points of the box edges are kept),
    so partly visible boxes still cover the right pixels; the rest is projected with the full
    camera model.
    """
    import cv2

    corners = box_corners(pose, size)
    R, t = image.camera_to_world[:3, :3], image.camera_to_world[:3, 3]
    cam = (corners - t) @ R
    front = cam[:, 2] > near
    if not front.any():
        return None
    pts = [cam[front]]
    for a, b in _EDGES:
        if front[a] != front[b]:
            w = (near - cam[a, 2]) / (cam[b, 2] - cam[a, 2])
            pts.append((cam[a] + w * (cam[b] - cam[a]))[None])
    world = np.concatenate(pts) @ R.T + t
    uv = image.project(world).uv
    hull = cv2.convexHull(np.round(uv).clip(-1e6, 1e6).astype(np.int32))  # far-off corners stay int32
    return hull.reshape(-1, 2)
