"""Rolling shutter of recorded images at render time: the image's readout and its camera's motion.

A rolling shutter is a property of a recorded image. A render for camera ``sensor`` at the time
of one of that camera's recorded images gets that image's timing. It also gets the camera's
velocity, a central difference along the camera's own path
(:class:`~idsplat_ns.data.rolling_shutter.CameraPath`). Every other render is global-shutter: a
viewer time between images, or a camera path. So are images whose data says global shutter (no
timing, readout 0, direction ``global``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import torch
from torch import Tensor

from idsplat_ns.data.camera import CameraImage, RollingShutter
from idsplat_ns.data.rolling_shutter import camera_paths, is_rolling, time_plane
from idsplat_ns.render import CameraMotion, ShutterTiming


@dataclass
class ImageShutter:
    """Rolling shutter of one recorded image."""

    shutter: RollingShutter
    """Readout time and direction."""
    width: int
    """Image width at which the readout applies (the recorded image's)."""
    height: int
    """Image height at which the readout applies."""
    linear_velocity: np.ndarray
    """[3] world-frame velocity of the camera centre, m/s."""
    angular_velocity: np.ndarray
    """[3] world-frame angular velocity of the camera, rad/s."""

    def motion(self, width: int, height: int, device=None, velocities: Optional[Tensor] = None) -> CameraMotion:
        """The rasterizer's :class:`CameraMotion` for a ``width`` x ``height`` render of this image;
        ``velocities`` [N, 3] are the Gaussians' world-frame velocities (None: all static)."""
        plane = time_plane(self.shutter, width, height, self.width, self.height)
        return CameraMotion(
            timing=ShutterTiming.from_planes([plane], device=device),
            linear_velocity=torch.as_tensor(self.linear_velocity, dtype=torch.float64, device=device)[None],
            angular_velocity=torch.as_tensor(self.angular_velocity, dtype=torch.float64, device=device)[None],
            velocities=velocities,
        )


class ShutterLookup:
    """The rolling shutter of each recorded image, found by camera and time."""

    def __init__(self, images: Sequence[CameraImage], camera_names: Sequence[str], tolerance: float = 1e-4) -> None:
        """``images``: all of the scene's images (their poses give the camera paths);
        ``camera_names``: sensor index -> camera name; ``tolerance``: seconds within which a render
        time is the image's own."""
        self.tolerance = tolerance
        self.camera_names = list(camera_names)
        paths = camera_paths(images)
        self._by_camera: dict[str, tuple[np.ndarray, list[ImageShutter]]] = {}
        for cam in self.camera_names:
            ims = sorted((im for im in images if im.camera == cam and is_rolling(im.rolling_shutter)), key=lambda im: im.time)
            if not ims:
                continue
            entries = []
            for im in ims:
                lin, ang = paths[cam].velocity_at(im.time)
                entries.append(ImageShutter(im.rolling_shutter, im.intrinsics.width, im.intrinsics.height, lin, ang))
            self._by_camera[cam] = (np.array([im.time for im in ims]), entries)

    @property
    def has_rolling_shutter(self) -> bool:
        """Whether any recorded image has a rolling shutter."""
        return bool(self._by_camera)

    def at(self, sensor: int, time: Optional[float]) -> Optional[ImageShutter]:
        """The rolling shutter of camera ``sensor``'s image at ``time``; None when there is no such
        image or it is global-shutter."""
        if time is None or not 0 <= sensor < len(self.camera_names):
            return None
        found = self._by_camera.get(self.camera_names[sensor])
        if found is None:
            return None
        times, entries = found
        k = int(np.argmin(np.abs(times - time)))
        return entries[k] if abs(times[k] - time) <= self.tolerance else None
