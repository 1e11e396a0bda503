"""Lidar sweeps as rays: origin and direction in the world, range, intensity, time, return flag.

Rays that returned nothing are kept (``returned`` false, ``ranges`` 0): they supervise ray drop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np


@dataclass
class LidarSweep:
    """One sweep (one dataset frame) of one or several lidars, all as world-frame rays."""

    frame_index: int
    """Index of the dataset frame this sweep belongs to."""
    time: float
    """Sweep reference time, seconds since the sequence start (float64)."""
    raw_timestamp: float
    """The dataset's own timestamp of the sweep, for reference only."""
    sensor_to_world: np.ndarray
    """[4, 4] pose of the main lidar at ``time`` in the recentred world."""
    origins: np.ndarray
    """[N, 3] float64 world position of the sensor when each ray was fired."""
    directions: np.ndarray
    """[N, 3] float64 unit directions in the world."""
    ranges: np.ndarray
    """[N] float64 metres along the direction; 0 where nothing returned."""
    intensities: np.ndarray
    """[N] float32 in [0, 1]; 0 where nothing returned."""
    times: np.ndarray
    """[N] float64 seconds since the sequence start, per ray."""
    returned: np.ndarray
    """[N] bool, False for rays that returned nothing."""
    sensor_ids: np.ndarray
    """[N] int16 which lidar fired the ray (PandaSet: 0 Pandar64, 1 PandarGT; Waymo: laser name)."""
    beam_ids: Optional[np.ndarray] = None
    """[N] int16 beam (row) index where the dataset gives it."""
    metadata: dict = field(default_factory=dict)
    """Dataset-specific extras."""

    def __post_init__(self) -> None:
        n = len(self.origins)
        for name in ("directions", "ranges", "intensities", "times", "returned", "sensor_ids"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"LidarSweep.{name} has {len(getattr(self, name))} rows, origins has {n}")

    @property
    def num_rays(self) -> int:
        return len(self.origins)

    @property
    def points(self) -> np.ndarray:
        """[M, 3] world points of the rays that returned."""
        r = self.returned
        return self.origins[r] + self.directions[r] * self.ranges[r, None]

    def select(self, mask: np.ndarray) -> "LidarSweep":
        """The sweep restricted to the rays where ``mask`` [N] is true."""
        return LidarSweep(
            frame_index=self.frame_index,
            time=self.time,
            raw_timestamp=self.raw_timestamp,
            sensor_to_world=self.sensor_to_world,
            origins=self.origins[mask],
            directions=self.directions[mask],
            ranges=self.ranges[mask],
            intensities=self.intensities[mask],
            times=self.times[mask],
            returned=self.returned[mask],
            sensor_ids=self.sensor_ids[mask],
            beam_ids=None if self.beam_ids is None else self.beam_ids[mask],
            metadata=dict(self.metadata),
        )


def rays_from_points(origins: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions [N, 3] and ranges [N] of rays from origins [N, 3] to points [N, 3]."""
    delta = np.asarray(points, dtype=np.float64) - origins
    ranges = np.linalg.norm(delta, axis=1)
    directions = delta / np.maximum(ranges, 1e-9)[:, None]
    return directions, ranges
