"""Plain records of what the v1 and v2 readers extract, before conversion to the project's Scene.

Both readers produce these in the dataset's own conventions (vehicle frame, Waymo camera axes, raw
world coordinates, raw timestamps); :mod:`idsplat_ns.data.waymo.assemble` converts them once. So a
v1 segment and the same data in v2 layout give the same scene by construction of one converter.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

CAMERA_NAMES = {1: "FRONT", 2: "FRONT_LEFT", 3: "FRONT_RIGHT", 4: "SIDE_LEFT", 5: "SIDE_RIGHT"}
"""Waymo CameraName.Name values to names (v1 and v2 share the numbers)."""
LASER_NAMES = {1: "TOP", 2: "FRONT", 3: "SIDE_LEFT", 4: "SIDE_RIGHT", 5: "REAR"}
"""Waymo LaserName.Name values to names."""
LABEL_TYPES = {0: "unknown", 1: "vehicle", 2: "pedestrian", 3: "sign", 4: "cyclist"}
"""Waymo Label.Type values to the project's lower-case label names."""
SHUTTER_DIRECTIONS = {0: "global", 1: "top_to_bottom", 2: "left_to_right", 3: "bottom_to_top", 4: "right_to_left", 5: "global"}
"""Waymo RollingShutterReadOutDirection values to :class:`RollingShutter` directions (unknown: global)."""


@dataclass
class CameraCalib:
    """One camera's calibration, as Waymo gives it."""

    name: str
    intrinsic: np.ndarray
    """[9] f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3."""
    extrinsic: np.ndarray
    """[4, 4] Waymo camera frame (x forward, y left, z up) to vehicle."""
    width: int
    height: int
    rolling_shutter_direction: int


@dataclass
class LidarCalib:
    """One lidar's calibration."""

    name: str
    extrinsic: np.ndarray
    """[4, 4] lidar to vehicle."""
    beam_inclinations: Optional[np.ndarray]
    """[H] radians, bottom row first, where non-uniform (TOP); None for a uniform spread."""
    inclination_min: float
    inclination_max: float


@dataclass
class CameraFrame:
    """One camera image of one frame."""

    name: str
    image: bytes
    """The JPEG as stored."""
    pose: np.ndarray
    """[4, 4] vehicle to raw world at ``pose_timestamp``."""
    pose_timestamp: float
    """Unix seconds."""
    shutter: float
    """Exposure per row/column, seconds."""
    trigger_time: float
    readout_done_time: float
    panoptic_label: Optional[bytes] = None
    """uint16 PNG of semantic * divisor + instance, where labelled."""
    panoptic_label_divisor: int = 0


@dataclass
class LidarFrame:
    """One lidar's range images in one frame."""

    name: str
    return1: np.ndarray
    """[H, W, 4] float32 range, intensity, elongation, no-label-zone."""
    return2: Optional[np.ndarray]
    """[H, W, 4] second return, or None."""
    pixel_pose: Optional[np.ndarray]
    """[H, W, 6] roll, pitch, yaw, x, y, z vehicle-to-world per pixel (TOP only), or None."""


@dataclass
class BoxLabel:
    """One 3D box label (``laser_labels``) in the frame's vehicle frame."""

    id: str
    type: int
    center: np.ndarray
    """[3] metres, vehicle frame."""
    size: np.ndarray
    """[3] length (x), width (y), height (z)."""
    heading: float
    """Radians about +z."""
    speed: np.ndarray
    """[3] m/s (vehicle frame axes)."""
    num_lidar_points: int
    num_top_lidar_points: int = 0


@dataclass
class FrameRecord:
    """Everything kept from one frame."""

    index: int
    """Frame number in the segment (0 = first record / first timestamp)."""
    timestamp_micros: int
    """Start of the TOP lidar sweep."""
    pose: np.ndarray
    """[4, 4] vehicle to raw world (about the middle of the sweep)."""
    cameras: list[CameraFrame] = field(default_factory=list)
    lidars: list[LidarFrame] = field(default_factory=list)
    labels: list[BoxLabel] = field(default_factory=list)
    projected_labels: dict = field(default_factory=dict)
    """camera name -> list of (label id, [4] u_min, v_min, u_max, v_max) from ``projected_lidar_labels`` (v1)."""


@dataclass
class SegmentCalibration:
    """Segment-level information."""

    context_name: str
    cameras: dict[str, CameraCalib]
    lidars: dict[str, LidarCalib]
    stats: dict = field(default_factory=dict)
