"""The scene representation shared by every parser (see ../shared/DESIGN.md).

A :class:`Scene` is a recentred, time-normalised driving sequence: camera images with poses and
intrinsics, lidar sweeps as rays, and (for evaluation only) ground-truth object tracks. The
raw-to-recentred transform and the raw time origin are kept so results can be mapped back.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.geometry import make_pose
from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.tracks import ObjectTrack
from idsplat_ns.data.validation import warn


def recentring_transform(first_ego_pose_raw: np.ndarray) -> np.ndarray:
    """world_from_raw [4, 4]: a pure translation that puts the first ego position at the origin.

    Only the translation is removed, so the dataset's world axes (z up) are kept; the large
    UTM-like offsets that would lose precision in float32 are gone.
    """
    return make_pose(np.eye(3), -np.asarray(first_ego_pose_raw, dtype=np.float64)[:3, 3])


@dataclass
class Scene:
    """One driving sequence in the project's conventions (metres, z up, seconds from the start)."""

    name: str
    """Sequence name (PandaSet ``001``, Waymo context name, synthetic ``street-seed0``)."""
    source: str
    """Which parser made it: ``pandaset``, ``waymo`` or ``synthetic``."""
    root: Optional[Path]
    """Where the sequence is on disk (None when built in memory)."""
    frame_indices: np.ndarray
    """[F] int dataset frame indices kept (after start/end selection), increasing."""
    frame_times: np.ndarray
    """[F] float64 seconds since the sequence start, one per kept frame (the lidar sweep time)."""
    ego_poses: np.ndarray
    """[F, 4, 4] ego (vehicle or main lidar) to world, recentred."""
    images: list[CameraImage]
    """Every camera image, ordered by frame then camera."""
    lidar: list[LidarSweep]
    """One sweep per kept frame (may be empty for camera-only data)."""
    tracks: list[ObjectTrack] = field(default_factory=list)
    """Ground-truth tracks: evaluation and the named oracle mode only."""
    world_from_raw: np.ndarray = field(default_factory=lambda: np.eye(4))
    """[4, 4] maps the dataset's world coordinates to the recentred world."""
    time_origin_raw: float = 0.0
    """The dataset timestamp (in its own unit) that is t = 0."""
    raw_time_unit_seconds: float = 1.0
    """Seconds per unit of the dataset's timestamps (1 for unix seconds, 1e-6 for microseconds)."""
    metadata: dict = field(default_factory=dict)
    """Parser-specific information (dataset version, generator settings, ...)."""

    def lidar_positions(self) -> np.ndarray:  # -> [F, 3]
        """Where the lidar was (world) at each frame's sweep."""
        return np.stack([sweep.sensor_to_world[:3, 3] for sweep in self.lidar])

    @property
    def camera_names(self) -> list[str]:
        """Camera names in first-seen order."""
        return list(dict.fromkeys(im.camera for im in self.images))

    @property
    def has_lidar(self) -> bool:
        return any(sweep.num_rays > 0 for sweep in self.lidar)

    @property
    def num_frames(self) -> int:
        return len(self.frame_indices)

    def raw_time_to_seconds(self, raw: np.ndarray | float) -> np.ndarray:
        """Convert dataset timestamps to seconds since the sequence start (float64)."""
        return (np.asarray(raw, dtype=np.float64) - self.time_origin_raw) * self.raw_time_unit_seconds

    def raw_points_to_world(self, points_raw: np.ndarray) -> np.ndarray:
        """Map points [N, 3] in the dataset's world frame to the recentred world."""
        T = self.world_from_raw
        return np.asarray(points_raw, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]

    def images_of(self, camera: str) -> list[CameraImage]:
        """The images of one camera in frame order."""
        return [im for im in self.images if im.camera == camera]

    def closest_sweep(self, time: float) -> Optional[LidarSweep]:
        """The lidar sweep whose reference time is closest to ``time`` (None without lidar)."""
        if not self.lidar:
            return None
        return min(self.lidar, key=lambda s: abs(s.time - time))

    def all_lidar_points(
        self, max_points: Optional[int] = None, seed: int = 0, frames: Optional[set[int]] = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """World points [M, 3] of every returned ray and their times [M], optionally only of the
        sweeps whose dataset frame index is in ``frames`` (e.g. the training split), subsampled."""
        sweeps = [s for s in self.lidar if frames is None or s.frame_index in frames]
        pts = [s.points for s in sweeps]
        times = [s.times[s.returned] for s in sweeps]
        if not pts:
            return np.zeros((0, 3)), np.zeros(0)
        points, point_times = np.concatenate(pts), np.concatenate(times)
        if max_points is not None and len(points) > max_points:
            keep = np.sort(np.random.default_rng(seed).choice(len(points), max_points, replace=False))
            points, point_times = points[keep], point_times[keep]
        return points, point_times

    def subset(self, frame_indices: set[int]) -> "Scene":
        """The same scene restricted to some dataset frames (e.g. the training split), same world and clock."""
        keep = np.array([f in frame_indices for f in self.frame_indices], dtype=bool)
        return replace(
            self,
            frame_indices=self.frame_indices[keep],
            frame_times=self.frame_times[keep],
            ego_poses=self.ego_poses[keep],
            images=[im for im in self.images if im.frame_index in frame_indices],
            lidar=[s for s in self.lidar if s.frame_index in frame_indices],
        )

    def summary(self) -> str:
        """One line describing the scene, for logs."""
        rays = sum(s.num_rays for s in self.lidar)
        span = float(self.frame_times[-1] - self.frame_times[0]) if self.num_frames else 0.0
        return (
            f"{self.source} scene {self.name}: {self.num_frames} frames over {span:.1f} s, "
            f"{len(self.images)} images from {len(self.camera_names)} cameras, "
            f"{len(self.lidar)} lidar sweeps ({rays} rays), {len(self.tracks)} GT tracks"
        )


def note_empty_sweeps(scene: Scene) -> list[int]:
    """Say once (stderr) which frames' lidar sweeps returned no point: training goes on without
    them, but a user should know their lidar is missing there. Returns those frame indices."""
    empty = [s.frame_index for s in scene.lidar if not np.any(s.returned)]
    if empty:
        shown = ", ".join(str(f) for f in empty[:10]) + (", ..." if len(empty) > 10 else "")
        warn(f"{scene.name}: the lidar sweeps of {len(empty)} of {len(scene.lidar)} frames hold no point (frames {shown}); "
             "training goes on without their points", key=f"empty-sweeps:{scene.name}")
    return empty
