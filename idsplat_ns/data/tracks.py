"""Ground-truth object tracks (boxes over time). For evaluation and the named oracle mode only.

A track's pose maps the box frame to the world: x forward along the object's length, y left,
z up, origin at the box centre. ``size`` is (length, width, height).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

ROAD_USER_CLASSES: tuple[str, ...] = ("vehicle", "pedestrian", "cyclist")
"""The classes of the paper's evaluation; any other label is ``other`` (signs, cones, animals)."""

# Lower-case dataset, detector-prompt and user labels of each class: PandaSet cuboid labels, Waymo
# label types, the paper's Grounded-SAM-2 prompts and common synonyms.
VEHICLE_LABELS = frozenset(
    {"car", "pickup truck", "medium-sized truck", "semi-truck", "bus", "van", "truck", "vehicle",
     "other vehicle - construction vehicle", "other vehicle - uncommon", "other vehicle - pedicab",
     "emergency vehicle", "towed object", "train", "tram / subway", "trolley", "tram", "suv"}
)
PEDESTRIAN_LABELS = frozenset({"pedestrian", "pedestrian with object", "human", "person", "people", "child", "adult"})
CYCLIST_LABELS = frozenset({"cyclist", "bicycle", "motorcycle", "motorized scooter", "personal mobility device",
                            "bike", "motorbike", "motorcyclist", "scooter", "rider", "two-wheeler"})


def label_group(label: str) -> str:
    """Map a dataset, detector or user label to ``vehicle``, ``pedestrian``, ``cyclist`` or ``other``."""
    key = label.strip().lower()
    if key in VEHICLE_LABELS:
        return "vehicle"
    if key in PEDESTRIAN_LABELS:
        return "pedestrian"
    if key in CYCLIST_LABELS:
        return "cyclist"
    return "other"


# Limits of the class guess from footprint and speed, for sources without a label (lidar motion,
# a trained instance's Gaussians). Footprints on the ground along the principal axes: pedestrian
# <= 1 x 1 m; bicycle or motorbike with rider ~2 x 0.5 m (handlebars and body give it depth); a
# car seen from behind ~1.8 x 1.3 m, a single flat face of a car < 0.25 m deep. Speeds: walking
# <= 2.5 m/s (running 3-4).
PEDESTRIAN_MAX_FOOTPRINT = (1.3, 1.1)  # (length, width) metres
CYCLIST_MAX_LENGTH = 2.7  # metres
CYCLIST_WIDTH = (0.25, 0.9)  # metres: thinner is one face of a larger object, wider a vehicle
PEDESTRIAN_MAX_SPEED = 3.5  # m/s: a pedestrian-sized object faster than this is a (head-on) cyclist


def class_from_size_speed(length: float, width: float, speed: float) -> str:
    """``vehicle``, ``pedestrian`` or ``cyclist`` from a footprint (metres, any order) and a mean
    speed (m/s; NaN when unknown); ``other`` without a finite footprint."""
    length, width = max(length, width), min(length, width)
    if not (np.isfinite(length) and length > 0):
        return "other"
    fast = np.isfinite(speed) and speed > PEDESTRIAN_MAX_SPEED
    if length <= PEDESTRIAN_MAX_FOOTPRINT[0] and width <= PEDESTRIAN_MAX_FOOTPRINT[1] and not fast:
        return "pedestrian"
    if length <= CYCLIST_MAX_LENGTH and CYCLIST_WIDTH[0] <= width <= CYCLIST_WIDTH[1]:
        return "cyclist"
    return "vehicle"


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
        """The evaluation class: ``vehicle``, ``pedestrian``, ``cyclist`` or ``other``."""
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
