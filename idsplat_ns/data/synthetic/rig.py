"""Sensor rig of the ego vehicle: camera intrinsics and mounts, lidar mount and beam pattern.

Ego frame: x forward, y left, z up, origin at the footprint centre on the ground.
Camera frame: OpenCV (x right, y down, z forward). Lidar frame (PandaSet): x right, y forward, z up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idsplat_ns.data.synthetic.config import SIDE_CAMERA_YAWS_DEG, SyntheticConfig, camera_names
from idsplat_ns.data.synthetic.world import World

CAMERA_MOUNTS = np.array([[1.60, 0.00, 1.55], [1.45, 0.45, 1.55], [1.45, -0.45, 1.55],
                          [0.90, 0.80, 1.55], [0.90, -0.80, 1.55]])
"""Camera positions in the ego frame (front, front-left, front-right, left, right)."""
SIDE_CAMERA_TIME_OFFSETS = (0.019, -0.015)
"""Image time minus frame time of the left and right cameras (they fire later in the sweep)."""
SIDE_CAMERA_GAINS = ((1.02, 0.97, 1.0), (0.98, 1.0, 1.03))
"""RGB gains of the left and right cameras."""

# Lidar axes in the ego frame: x_lidar = right = -y_ego, y_lidar = forward, z_lidar = up.
EGO_FROM_LIDAR = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def camera_rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Ego-from-camera rotation [3, 3] for a camera looking at yaw (left positive) and pitch (up positive)."""
    yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
    forward = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics and mount of one camera."""

    name: str
    """PandaSet camera name."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    fx: float
    """Focal length x, pixels."""
    fy: float
    """Focal length y, pixels."""
    cx: float
    """Principal point x, pixels (pixel i spans [i, i + 1], its centre is i + 0.5)."""
    cy: float
    """Principal point y, pixels."""
    ego_from_camera: np.ndarray  # [3, 3]
    """Mount rotation."""
    mount: np.ndarray  # [3]
    """Mount position in the ego frame."""
    time_offset: float
    """Image time minus frame time, seconds."""
    gain: np.ndarray  # [3]
    """RGB gain of this camera."""

    def pose(self, world: World, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Street-from-camera rotation [3, 3] and position [3] at time `t`."""
        rot, pos = world.ego_pose(np.array([t]))
        return rot[0] @ self.ego_from_camera, pos[0] + rot[0] @ self.mount

    def poses(self, world: World, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Street-from-camera rotations [K, 3, 3] and positions [K, 3] at times `t` [K] (the lines
        of a rolling-shutter image)."""
        rot, pos = world.ego_pose(np.asarray(t, dtype=np.float64))
        return rot @ self.ego_from_camera, pos + rot @ self.mount


def cameras(config: SyntheticConfig) -> list[PinholeCamera]:
    """The cameras of the rig: the three front ones, and the two side ones where the rig has them."""
    rig = config.cameras
    fx = 0.5 * rig.image_width / np.tan(np.radians(rig.horizontal_fov_deg) / 2)
    yaws = tuple(rig.yaws_deg) + SIDE_CAMERA_YAWS_DEG
    offsets = tuple(rig.time_offsets) + SIDE_CAMERA_TIME_OFFSETS
    gains = tuple(rig.color_gains) + SIDE_CAMERA_GAINS
    out = []
    for i, name in enumerate(camera_names(rig)):
        out.append(
            PinholeCamera(
                name=name,
                width=rig.image_width,
                height=rig.image_height,
                fx=float(fx),
                fy=float(fx),
                cx=rig.image_width / 2,
                cy=rig.image_height / 2,
                ego_from_camera=camera_rotation(yaws[i], rig.pitch_deg),
                mount=CAMERA_MOUNTS[i],
                time_offset=offsets[i],
                gain=np.asarray(gains[i], dtype=np.float64),
            )
        )
    return out


def beam_elevations(low_deg: float = -25.0, high_deg: float = 15.0) -> np.ndarray:
    """64 beam elevations [64] in degrees, top to bottom, densest around the horizon.

    Like the Pandar64: 8 sparse beams above +2 deg, 40 beams 0.2 deg apart from +2 to -5.8 deg,
    16 beams spreading to the lowest elevation. Scaled to `low_deg`/`high_deg` at the ends.
    """
    top = np.linspace(high_deg, 2.6, 8)
    middle = np.linspace(2.0, -5.8, 40)
    bottom = np.linspace(-6.6, low_deg, 16)
    return np.concatenate([top, middle, bottom])


def lidar_pose(world: World, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Street-from-lidar rotations [N, 3, 3] and positions [N, 3] at times `t` [N]."""
    rot, pos = world.ego_pose(t)
    mount = np.array([0.0, 0.0, world.config.lidar.mount_height])
    return rot @ EGO_FROM_LIDAR, pos + rot @ mount
