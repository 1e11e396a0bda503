"""Ground-truth object tracks (boxes over time). For evaluation and the named oracle mode only.

A track's pose maps the box frame to the world: x forward along the object's length, y left,
z up, origin at the box centre. ``size`` is (length, width, height).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

# Class groups of the paper's evaluation (vehicle / pedestrian / cyclist); lower-case labels.
VEHICLE_LABELS = frozenset(
    {"car", "pickup truck", "medium-sized truck", "semi-truck", "bus", "van", "truck", "vehicle",
     "other vehicle - construction vehicle", "other vehicle - uncommon", "other vehicle - pedicab",
     "emergency vehicle", "towed object", "train", "tram / subway"}
)
PEDESTRIAN_LABELS = frozenset({"pedestrian", "pedestrian with object", "human"})
CYCLIST_LABELS = frozenset({"cyclist", "bicycle", "motorcycle", "motorized scooter", "personal mobility device"})


def label_group(label: str) -> str:
    """Map a dataset label to ``vehicle``, ``pedestrian``, ``cyclist`` or ``other``."""
    key = label.strip().lower()
    if key in VEHICLE_LABELS:
        return "vehicle"
    if key in PEDESTRIAN_LABELS:
        return "pedestrian"
    if key in CYCLIST_LABELS:
        return "cyclist"
    return "other"


@dataclass
class ObjectTrack:
    """One annotated object over the frames where it is annotated."""

    track_id: str
    """The dataset's object ID (PandaSet uuid, Waymo label id)."""
    label: str
    """The dataset's class name."""
    frame_indices: np.ndarray
    """[T] int, increasing dataset frame indices where the object is annotated."""
    times: np.ndarray
    """[T] float64 seconds since the sequence start."""
    poses: np.ndarray
    """[T, 4, 4] box-to-world in the recentred world."""
    size: np.ndarray
    """[3] length, width, height (metres); the median over the track."""
    moving: bool
    """Whether the object moves at any time in the sequence (dataset flag or speed)."""
    speeds: Optional[np.ndarray] = None
    """[T] m/s where the dataset gives them."""
    num_lidar_points: Optional[np.ndarray] = None
    """[T] lidar points inside the box where the dataset gives them (the paper's >= 10 filter)."""
    metadata: dict = field(default_factory=dict)

    @property
    def group(self) -> str:
        return label_group(self.label)

    def index_of_frame(self, frame_index: int) -> Optional[int]:
        """Row of ``frame_index`` in this track's arrays, or None where the object is not annotated."""
        hit = np.nonzero(self.frame_indices == frame_index)[0]
        return None if len(hit) == 0 else int(hit[0])

    def pose_at_frame(self, frame_index: int) -> Optional[np.ndarray]:
        """Box-to-world [4, 4] at a frame, or None where the object is not annotated."""
        k = self.index_of_frame(frame_index)
        return None if k is None else self.poses[k]


def box_corners(pose: np.ndarray, size: np.ndarray) -> np.ndarray:
    """The 8 corners [8, 3] of a box with pose [4, 4] (box-to-world) and size (length, width, height)."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    local = signs * (np.asarray(size, dtype=np.float64) / 2)
    return local @ pose[:3, :3].T + pose[:3, 3]


def points_in_box(points: np.ndarray, pose: np.ndarray, size: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """[N] bool: which world points [N, 3] lie inside the box (optionally grown by ``margin`` metres)."""
    local = (np.asarray(points, dtype=np.float64) - pose[:3, 3]) @ pose[:3, :3]
    half = np.asarray(size, dtype=np.float64) / 2 + margin
    return np.all(np.abs(local) <= half, axis=1)
