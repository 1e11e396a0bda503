"""Waymo's own 2D box projections as a check of the camera model (bench and tests).

Each 3D laser label is projected with the scene's camera model; the axis-aligned rectangle of its
eight corners (clipped to the image) is compared edge by edge with Waymo's
``projected_lidar_labels`` of the same object.
"""

from __future__ import annotations

import numpy as np

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.tracks import ObjectTrack, box_corners


def box_projection_errors(image: CameraImage, tracks: list[ObjectTrack]) -> tuple[np.ndarray, np.ndarray]:
    """|edge error| [M, 4] in pixels (x_min, y_min, x_max, y_max) of every box Waymo projected into
    ``image``, and the largest normalised squared radius [M] of each box's corners (how far into
    the lens's periphery it reaches). Boxes reaching behind the camera are skipped."""
    labels = image.metadata["projected_lidar_labels"]
    size = np.array([image.intrinsics.width, image.intrinsics.height])
    errors, radii = [], []
    for track in tracks:
        box = labels.get(f"{track.track_id}_{image.camera}")
        if box is None:
            continue
        corners = box_corners(track.poses[0], track.metadata["sizes"][0])
        proj = image.project(corners)
        if np.any(proj.depth <= 0.1):
            continue
        rect = np.concatenate([np.clip(proj.uv.min(0), 0, size), np.clip(proj.uv.max(0), 0, size)])
        errors.append(np.abs(rect - box))
        cam = (corners - image.camera_to_world[:3, 3]) @ image.camera_to_world[:3, :3]
        radii.append(float(np.max(np.sum((cam[:, :2] / cam[:, 2:]) ** 2, 1))))
    return np.reshape(np.array(errors), (-1, 4)), np.array(radii)
