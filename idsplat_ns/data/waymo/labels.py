"""Waymo 3D box labels to ground-truth tracks (evaluation and the named oracle mode only).

A label's box lives in its frame's vehicle frame at the frame's start time: centre, (length,
width, height) along (x, y, z) and heading about +z. Its box-to-world pose is
``world_from_raw @ frame_pose @ [Rz(heading) | centre]``, with x forward along the length, as
:class:`ObjectTrack` expects.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.data.tracks import ObjectTrack
from idsplat_ns.data.waymo.records import LABEL_TYPES, BoxLabel

MOVING_SPEED_MPS = 1.0
"""A track is moving when its labelled speed exceeds this anywhere (m/s); static objects carry
label noise of a few cm/s."""
MIN_LIDAR_POINTS = 10
"""The paper's evaluation filter: boxes with fewer lidar points are not evaluated."""


def box_to_vehicle(label: BoxLabel) -> np.ndarray:
    """[4, 4] box-to-vehicle pose of one label."""
    return make_pose(rot_z(label.heading), label.center)


def build_tracks(
    frames: list[tuple[int, float, np.ndarray, list[BoxLabel]]],  # (frame index, time s, [4,4] vehicle-to-recentred-world, labels)
) -> list[ObjectTrack]:
    """Group labels by object ID over frames into tracks (frame order kept)."""
    per_id: dict[str, list] = defaultdict(list)
    for frame_index, time, vehicle_to_world, labels in frames:
        for label in labels:
            per_id[label.id].append((frame_index, time, vehicle_to_world @ box_to_vehicle(label), label))
    tracks = []
    for track_id, items in per_id.items():
        items.sort(key=lambda it: it[0])
        labels = [it[3] for it in items]
        speeds = np.array([float(np.linalg.norm(lb.speed)) for lb in labels])
        tracks.append(
            ObjectTrack(
                track_id=track_id,
                label=LABEL_TYPES.get(labels[0].type, "unknown"),
                frame_indices=np.array([it[0] for it in items], dtype=int),
                times=np.array([it[1] for it in items], dtype=np.float64),
                poses=np.stack([it[2] for it in items]),
                size=np.median(np.stack([lb.size for lb in labels]), axis=0),
                moving=bool(np.any(speeds > MOVING_SPEED_MPS)),
                speeds=speeds,
                num_lidar_points=np.array([lb.num_lidar_points for lb in labels], dtype=int),
                metadata={"waymo_type": labels[0].type, "sizes": np.stack([lb.size for lb in labels])},
            )
        )
    return tracks
