"""Pinhole cameras with Brown-Conrady distortion (OpenCV axes: x right, y down, z forward).

The distortion coefficients follow OpenCV's order ``(k1, k2, p1, p2, k3)``, which is also Waymo's
order; PandaSet images are already undistorted (all zeros).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np
from idsplat_ns.data.geometry import invert_pose


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of one image, in pixels of that image."""

    fx: float
    """Focal length along x (pixels)."""
    fy: float
    """Focal length along y (pixels)."""
    cx: float
    """Principal point x (pixels, origin at the top-left pixel's corner)."""
    cy: float
    """Principal point y (pixels)."""
    width: int
    """Image width (pixels)."""
    height: int
    """Image height (pixels)."""
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    """Brown-Conrady ``(k1, k2, p1, p2, k3)`` applied to normalised coordinates (OpenCV order)."""

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix (float64)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(c) > 0 for c in self.distortion)

    @property
    def max_valid_radius2(self) -> float:
        """Largest squared normalised radius where the radial distortion is still monotonic.

        Beyond it the polynomial folds back and points far outside the view would land inside the
        image; projection rejects them. Found as the first positive root s of
        d(r (1 + k1 r^2 + k2 r^4 + k3 r^6))/dr = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 (s = r^2).
        """
        k1, k2, _, _, k3 = self.distortion
        roots = np.roots([7 * k3, 5 * k2, 3 * k1, 1.0]) if any((k1, k2, k3)) else np.array([])
        positive = [r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0]
        return float(min(positive)) if positive else float("inf")

    def scaled(self, factor: float) -> "Intrinsics":
        """Intrinsics of the image resized by ``factor`` (0.5 halves it); the size is rounded."""
        width, height = int(round(self.width * factor)), int(round(self.height * factor))
        sx, sy = width / self.width, height / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy, width=width, height=height)


def distort_normalized(xy: np.ndarray, distortion: tuple[float, ...]) -> np.ndarray:
    """Apply Brown-Conrady distortion to normalised image coordinates xy [N, 2] (x/z, y/z)."""
    k1, k2, p1, p2, k3 = distortion
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], -1)


def undistort_normalized(xy_d: np.ndarray, distortion: tuple[float, ...], iterations: int = 20) -> np.ndarray:
    """Invert :func:`distort_normalized` by fixed-point iteration (as OpenCV's undistortPoints does)."""
    k1, k2, p1, p2, k3 = distortion
    xy = xy_d.copy()
    for _ in range(iterations):
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        xy = np.stack([(xy_d[:, 0] - dx) / radial, (xy_d[:, 1] - dy) / radial], -1)
    return xy


@dataclass(frozen=True)
class Projection:
    """Where world points land in an image."""

    uv: np.ndarray
    """[N, 2] pixel coordinates (x right, y down), float64."""
    depth: np.ndarray
    """[N] z in the camera frame (metres); <= 0 behind the camera."""
    valid: np.ndarray
    """[N] bool: in front of the camera and inside the image."""


def project_points(
    points_world: np.ndarray,  # [N, 3] float64
    camera_to_world: np.ndarray,  # [4, 4] OpenCV axes, or [N, 4, 4]: one pose per point
    intrinsics: Intrinsics,
    min_depth: float = 1e-3,
) -> Projection:
    """Project world points with the full camera model (pose, pinhole, distortion). A pose per
    point serves rolling-shutter images, where each line has its own pose."""
    pts = np.asarray(points_world, dtype=np.float64)
    R, t = camera_to_world[..., :3, :3], camera_to_world[..., :3, 3]
    # R^T (p - t), row-vector form
    cam = (pts - t) @ R if R.ndim == 2 else np.einsum("ni,nij->nj", pts - t, R)
    depth = cam[:, 2]
    front = depth > min_depth
    xy = cam[:, :2] / np.where(front, depth, 1.0)[:, None]
    if intrinsics.has_distortion:
        # The polynomial folds back outside the lens's monotonic range: such points are not seen.
        front &= np.sum(xy * xy, 1) < intrinsics.max_valid_radius2
        xy = distort_normalized(xy, intrinsics.distortion)
    u = intrinsics.fx * xy[:, 0] + intrinsics.cx
    v = intrinsics.fy * xy[:, 1] + intrinsics.cy
    uv = np.stack([u, v], -1)
    inside = (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)
    return Projection(uv=uv, depth=depth, valid=front & inside)


def pixel_rays(
    uv: np.ndarray,  # [N, 2] pixel coordinates
    camera_to_world: np.ndarray,  # [4, 4]
    intrinsics: Intrinsics,
) -> tuple[np.ndarray, np.ndarray]:
    """World-frame ray origins [N, 3] and unit directions [N, 3] through pixels (undistorting them)."""
    xy = np.stack([(uv[:, 0] - intrinsics.cx) / intrinsics.fx, (uv[:, 1] - intrinsics.cy) / intrinsics.fy], -1)
    if intrinsics.has_distortion:
        xy = undistort_normalized(xy, intrinsics.distortion)
    d_cam = np.concatenate([xy, np.ones((len(xy), 1))], 1)
    d = d_cam @ camera_to_world[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(camera_to_world[:3, 3], d.shape).copy(), d


@dataclass
class RollingShutter:
    """Rolling-shutter timing of an image (Waymo gives it; PandaSet and the synthetic street do not)."""

    readout_seconds: float
    """Time from the first to the last row (or column) being exposed."""
    direction: str
    """Readout direction: ``top_to_bottom``, ``left_to_right``, ``bottom_to_top``, ``right_to_left`` or ``global``."""


@dataclass
class CameraImage:
    """One image of one camera: where it was, when, and where its pixels are."""

    camera: str
    """Camera name (the dataset's, e.g. ``front_camera`` or ``FRONT``)."""
    frame_index: int
    """Index of the dataset frame (sweep) that this image belongs to."""
    time: float
    """Seconds since the sequence start (float64), the image's mid-exposure time."""
    raw_timestamp: float
    """The dataset's own timestamp (unix seconds or microseconds), for reference only."""
    camera_to_world: np.ndarray
    """[4, 4] float64, OpenCV axes, in the recentred world."""
    intrinsics: Intrinsics
    """Intrinsics at the stored image's resolution (before any downscale the loader applies)."""
    image_path: Optional[Path] = None
    """Where the image is; None for images held in memory (``image``)."""
    image: Optional[np.ndarray] = None
    """[H, W, 3] uint8, for images decoded in memory (e.g. Waymo JPEG bytes)."""
    image_bytes: Optional[bytes] = None
    """Encoded image (JPEG/PNG) held in memory, decoded on demand."""
    rolling_shutter: Optional[RollingShutter] = None
    """Rolling-shutter timing where the dataset gives it."""
    instance_mask_path: Optional[Path] = None
    """Ground-truth uint16 instance-ID map (evaluation only), where the dataset has one."""
    metadata: dict = field(default_factory=dict)
    """Anything else the parser wants to keep (dataset-specific)."""

    def project(self, points_world: np.ndarray) -> Projection:
        """Project world points [N, 3] into this image (pixel coordinates and depth)."""
        return project_points(points_world, self.camera_to_world, self.intrinsics)

    @property
    def world_to_camera(self) -> np.ndarray:
        return invert_pose(self.camera_to_world)
