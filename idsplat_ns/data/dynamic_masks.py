"""Ground-truth dynamic-region masks (for DPSNR, per class): pixels of moving objects in an image.

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
from idsplat_ns.data.tracks import ROAD_USER_CLASSES, box_corners, label_group

MASK_KEYS: dict[str, str] = {
    "vehicle": "dynamic_mask", "pedestrian": "dynamic_mask_pedestrian", "cyclist": "dynamic_mask_cyclist"
}
"""Batch key of each class's dynamic mask; the model reports ``dpsnr`` + the key's suffix (the
paper's DPSNR over moving vehicles is ``dpsnr``)."""


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


def moving_object_map(scene: Scene, image: CameraImage, scale: float = 1.0) -> tuple[np.ndarray, list[str]]:
    """Which moving road user covers each pixel: ``[H, W]`` int32 (-1 none, else an index into the
    returned track IDs). From the dataset's instance masks where it has them (with its instance
    file's uuids), else the boxes' silhouettes, nearer boxes over farther ones."""
    intr = image.intrinsics.scaled(scale)
    instance_map = load_instance_mask(image, scale)
    classes = scene.metadata.get("gt_instances")
    out = np.full((intr.height, intr.width), -1, np.int32)
    ids: list[str] = []
    if instance_map is not None and classes is not None:
        for k, info in classes.items():
            if info.get("moving") and info.get("uuid") and label_group(info.get("label", "")) in ROAD_USER_CLASSES:
                hit = instance_map == int(k)
                if hit.any():
                    out[hit] = len(ids)
                    ids.append(str(info["uuid"]))
        return out, ids
    import cv2

    cam = image.camera_to_world[:3, 3]
    boxes = []
    for track in scene.tracks:
        k = track.index_of_frame(image.frame_index) if track.moving and track.group in ROAD_USER_CLASSES else None
        if k is not None:
            boxes.append((float(np.linalg.norm(track.poses[k][:3, 3] - cam)), track, k))
    for _, track, k in sorted(boxes, key=lambda b: -b[0]):  # far to near: the nearer box is drawn last
        poly = box_silhouette(_at_scale(image, intr), track.poses[k], track.size)
        if poly is not None and len(poly) >= 3:
            layer = np.zeros_like(out, np.uint8)
            cv2.fillConvexPoly(layer, poly, 1)
            if layer.any():
                out[layer.astype(bool)] = len(ids)
                ids.append(track.track_id)
    return out, ids


def moving_classes(scene: Scene) -> list[str]:
    """The road-user classes with moving annotated objects in the scene (tracks, or the classes
    file of the dataset's own instance masks), in :data:`ROAD_USER_CLASSES` order."""
    groups = {t.group for t in scene.tracks if t.moving}
    groups |= {label_group(v.get("label", "")) for v in (scene.metadata.get("gt_instances") or {}).values() if v.get("moving")}
    return [g for g in ROAD_USER_CLASSES if g in groups]


def class_dynamic_masks(scene: Scene, image: CameraImage, scale: float = 1.0) -> dict[str, np.ndarray]:
    """``{MASK_KEYS[class]: [H, W] bool}`` for each class with moving objects in the scene (an
    image where none is in view gets an empty mask; a class the scene lacks gets no key, so its
    DPSNR is absent, not zero)."""
    return {MASK_KEYS[g]: dynamic_mask(scene, image, scale, groups=(g,)) for g in moving_classes(scene)}


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
