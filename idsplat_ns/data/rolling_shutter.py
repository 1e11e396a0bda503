"""Rolling-shutter timing: when each pixel of an image was exposed, where its camera was then, and
where world points land in a rolling-shutter image.

One convention serves the renderer, the lifting stage and the synthetic generator.
``CameraImage.time`` is the mid-exposure of the image's centre line. Lines are exposed one after
another at a constant rate, and the first and last lines' mid-exposures are ``readout_seconds``
apart. ``c`` is the pixel coordinate across lines: y for ``top_to_bottom`` and ``bottom_to_top``,
x for ``left_to_right`` and ``right_to_left``, with pixel centres at ``i + 0.5``. ``L`` is the
image size along ``c``. Then

    tau(c) = s * (c - L / 2) / (L - 1) * readout_seconds

is the exposure time relative to ``CameraImage.time``, with ``s = +1`` for top-to-bottom and
left-to-right and ``-1`` for the other two directions. So line 0 is exposed at
``-s * readout / 2`` and the last line at ``+s * readout / 2``. In an image resized from the
full-resolution one (a downscaled render), the same physical line keeps its time
(:func:`time_plane`).

Poses between images come from interpolating the camera's own poses (:class:`CameraPath`);
velocities come from central differences of that path.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from idsplat_ns.data.camera import CameraImage, Projection, RollingShutter, project_points
from idsplat_ns.data.geometry import interpolate_poses, so3_log

DIRECTIONS: dict[str, tuple[int, int]] = {
    "top_to_bottom": (1, 1),
    "bottom_to_top": (1, -1),
    "left_to_right": (0, 1),
    "right_to_left": (0, -1),
}
"""Readout direction -> (pixel axis across lines: 0 = x, 1 = y; sign s)."""
GLOBAL = "global"
"""The direction of a global-shutter image (every pixel at ``CameraImage.time``)."""


def is_rolling(shutter: Optional[RollingShutter]) -> bool:
    """Whether ``shutter`` exposes lines at different times (not None, not global, readout > 0)."""
    return shutter is not None and shutter.direction in DIRECTIONS and shutter.readout_seconds > 0


def time_plane(
    shutter: Optional[RollingShutter],
    width: int,
    height: int,
    full_width: Optional[int] = None,
    full_height: Optional[int] = None,
) -> tuple[float, float, float]:
    """``(t0, du, dv)``: pixel ``(u, v)`` of a ``width`` x ``height`` image is exposed at
    ``t0 + du u + dv v`` seconds after ``CameraImage.time``. ``full_width``/``full_height`` give the
    size at which the readout was measured when the image is a resized copy (default: this size).
    All zeros for a global shutter."""
    if not is_rolling(shutter):
        return 0.0, 0.0, 0.0
    axis, sign = DIRECTIONS[shutter.direction]
    size = (width, height)[axis]
    full = (full_width if full_width is not None else width, full_height if full_height is not None else height)[axis]
    if full < 2:
        return 0.0, 0.0, 0.0
    # tau = s R (c_full - L_full / 2) / (L_full - 1) with c_full = c * L_full / L.
    rate = sign * shutter.readout_seconds / (full - 1)
    slope = rate * full / size
    t0 = -rate * full / 2
    return (t0, slope, 0.0) if axis == 0 else (t0, 0.0, slope)


def pixel_times(uv: np.ndarray, shutter: Optional[RollingShutter], width: int, height: int) -> np.ndarray:
    """[N] exposure times (seconds after ``CameraImage.time``) of pixel coordinates ``uv`` [N, 2]."""
    t0, du, dv = time_plane(shutter, width, height)
    return t0 + du * uv[:, 0] + dv * uv[:, 1]


def line_times(shutter: Optional[RollingShutter], width: int, height: int) -> tuple[int, np.ndarray]:
    """``(axis, tau)``: the pixel axis across lines (0 = x: columns, 1 = y: rows) and the exposure
    time [L] of every line's centre, seconds after ``CameraImage.time`` (zeros for a global shutter)."""
    axis = DIRECTIONS[shutter.direction][0] if is_rolling(shutter) else 1
    size = (width, height)[axis]
    centres = np.arange(size, dtype=np.float64) + 0.5
    uv = np.zeros((size, 2))
    uv[:, axis] = centres
    return axis, pixel_times(uv, shutter, width, height)


@dataclass
class CameraPath:
    """One camera's poses over time (its own images' poses), interpolated between them."""

    times: np.ndarray
    """[M] float64 seconds, increasing."""
    poses: np.ndarray
    """[M, 4, 4] camera-to-world (OpenCV axes) at those times."""

    def pose_at(self, t: float | np.ndarray) -> np.ndarray:
        """[4, 4] camera-to-world at time ``t`` (or [K, 4, 4] for an array of times); translation
        linear, rotation slerped; continued at constant velocity beyond the ends."""
        query = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = interpolate_poses(self.times, self.poses, query, extrapolate=True)
        return out[0] if np.ndim(t) == 0 else out

    def velocity_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """World-frame linear [3] (m/s) and angular [3] (rad/s) velocity of the camera at ``t``:
        central difference over one median image step (one-sided at the ends); zeros for a path
        of one pose."""
        if len(self.times) < 2:
            return np.zeros(3), np.zeros(3)
        h = 0.5 * float(np.median(np.diff(self.times)))
        lo = max(t - h, float(self.times[0]))
        hi = min(t + h, float(self.times[-1]))
        if hi - lo <= 1e-9:  # outside the span: the end segment's velocity
            lo, hi = (float(self.times[0]), float(self.times[1])) if t < self.times[0] else (
                float(self.times[-2]), float(self.times[-1]))
        a, b = self.pose_at(np.array([lo, hi]))
        linear = (b[:3, 3] - a[:3, 3]) / (hi - lo)
        angular = so3_log(b[:3, :3] @ a[:3, :3].T) / (hi - lo)  # world-frame: R(t) = exp(w t) R0
        return linear, angular


def camera_paths(images: Sequence[CameraImage]) -> dict[str, CameraPath]:
    """Each camera's path from its images (sorted by time; repeated times keep the first)."""
    by_camera: dict[str, list[CameraImage]] = {}
    for im in images:
        by_camera.setdefault(im.camera, []).append(im)
    paths = {}
    for cam, ims in by_camera.items():
        times = np.array([im.time for im in ims], dtype=np.float64)
        order = np.argsort(times, kind="stable")
        times = times[order]
        keep = np.concatenate([[True], np.diff(times) > 0])
        poses = np.stack([ims[i].camera_to_world for i in order])[keep]
        paths[cam] = CameraPath(times[keep], poses)
    return paths


def project_rolling(
    points_world: np.ndarray,  # [N, 3]
    image: CameraImage,
    path: Optional[CameraPath],
    iterations: int = 12,
    tolerance: float = 1e-10,
) -> tuple[Projection, np.ndarray]:
    """Project world points into a rolling-shutter image, each with the camera pose of the line it
    lands on. Returns the projection and each point's exposure time [N] (seconds after
    ``image.time``).

    The line time depends on where the point lands, and where it lands depends on the camera pose
    at that time. This fixed point is found by iteration, starting from the global-shutter
    projection. Each step shrinks the error by the point's pixel speed times the readout per
    line, far below one for any real camera. A global-shutter image, or no path, gives the plain
    projection and zeros.
    """
    pts = np.asarray(points_world, dtype=np.float64)
    intr = image.intrinsics
    if not is_rolling(image.rolling_shutter) or path is None or len(pts) == 0:
        return image.project(pts), np.zeros(len(pts))
    # Only points near the view can land in it: the rest keep the global projection (and stay
    # invalid), which spares the per-point poses of a whole sweep.
    proj = image.project(pts)
    margin = 0.5 * max(intr.width, intr.height)
    near = (proj.depth > 0) & np.all(np.isfinite(proj.uv), 1)
    near &= (proj.uv[:, 0] > -margin) & (proj.uv[:, 0] < intr.width + margin)
    near &= (proj.uv[:, 1] > -margin) & (proj.uv[:, 1] < intr.height + margin)
    tau = np.zeros(len(pts))
    idx = np.flatnonzero(near)
    if len(idx) == 0:
        return proj, tau
    # The image's own pose is the truth at tau = 0; the path only supplies the motion around it.
    delta = image.camera_to_world @ np.linalg.inv(path.pose_at(image.time))
    sub = Projection(uv=proj.uv[idx], depth=proj.depth[idx], valid=proj.valid[idx])
    sub_tau = np.zeros(len(idx))
    lo, hi = _time_bounds(image.rolling_shutter, intr.width, intr.height)
    for _ in range(iterations):
        new_tau = np.clip(pixel_times(sub.uv, image.rolling_shutter, intr.width, intr.height), lo, hi)
        new_tau = np.where(np.isfinite(new_tau), new_tau, 0.0)
        converged = np.max(np.abs(new_tau - sub_tau)) < tolerance
        sub_tau = new_tau
        sub = _project_at(pts[idx], sub_tau, image, path, delta)
        if converged:
            break
    proj.uv[idx], proj.depth[idx], proj.valid[idx], tau[idx] = sub.uv, sub.depth, sub.valid, sub_tau
    proj.valid[~near] = False
    return proj, tau


def _time_bounds(shutter: RollingShutter, width: int, height: int) -> tuple[float, float]:
    """Earliest and latest exposure time over the image area (the image's corners)."""
    t0, du, dv = time_plane(shutter, width, height)
    corners = [t0 + du * u + dv * v for u in (0.0, float(width)) for v in (0.0, float(height))]
    return min(corners), max(corners)


def _project_at(pts: np.ndarray, tau: np.ndarray, image: CameraImage, path: CameraPath, delta: np.ndarray) -> Projection:
    """Project each point with the camera pose at ``image.time + tau`` (one pose per point)."""
    poses = delta @ path.pose_at(image.time + tau)  # [N, 4, 4]
    return project_points(pts, poses, image.intrinsics)
