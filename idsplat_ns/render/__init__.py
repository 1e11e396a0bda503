"""Differentiable rasterizers for IDSplat (pure torch; gsplat kernels on CUDA).

Public API (all tensors torch, float32 unless stated; C cameras, N Gaussians):

``project_gaussians(means [N,3], quats [N,4] wxyz, scales [N,3], viewmats [C,4,4], Ks [C,3,3],
width, height, *, eps2d=0.3, near_plane=0.01, far_plane=1e10, radius_clip=0.0,
calc_compensations=False) -> Projection``
    EWA projection with gsplat 1.4.0's conventions: ``Projection.means2d`` [C,N,2],
    ``conics`` [C,N,3], ``depths`` [C,N], ``radii`` [C,N] int32 (0 = culled).

``rasterize_camera(means, quats, scales, opacities [N], features [N,D], viewmats, Ks, width,
height, *, instance_ids=None [N] int64, near_plane=0.01, far_plane=1e10, backend="auto",
eps2d=0.3, tile_size=8, return_instance_alpha=False, motion=None) -> CameraRender``
    Camera images: ``features`` [C,H,W,D], ``alpha`` [C,H,W,1], ``depth`` (expected) and
    ``median_depth`` [C,H,W,1], ``instance_id`` [C,H,W] int64 (-1 where empty), ``means2d``,
    ``radii``. No background is composited. ``motion`` (:class:`CameraMotion`): rolling shutter,
    each Gaussian drawn where it is when its line is exposed (see :mod:`.rolling_shutter`).

``rasterize_lidar(means [N,3] or [K,N,3], quats [N,4] or [K,N,4], scales [N,3], opacities [N],
features [N,D], lidar_from_world [4,4] or [K,4,4], ray_azimuth [R], ray_elevation [R], *,
ray_bins=None [R], azimuth_resolution=radians(0.2), elevation_resolution=radians(0.2),
near_plane=0.01, far_plane=1e10, eps2d=0.3, tile_size=8, ray_cutoff=None [R], cull=True) -> LidarRender``
    Per-ray ``features`` [R,D], ``alpha`` [R,1], expected ``range`` and ``median_range`` [R,1];
    with ``ray_cutoff`` also ``alpha_before_cutoff`` [R,1] (the summed alpha of the Gaussians in
    front of each ray's cut-off range: the line-of-sight loss); ``cull`` skips Gaussians that no
    ray of their time bin can reach. K time bins for rolling sweeps (see :mod:`.lidar`).

``rasterize_dense(...)``
    The dense every-Gaussian-against-every-pixel reference (tests and benchmarks only).

See ``docs/rendering.md`` for the compositing rules, the speed table and design notes.

Layer: beside ``data``, above ``errors``, ``atomic`` and ``_compat``, which are all it may import
of the project.
"""

from .lidar import LidarRender, rasterize_lidar
from .camera import rasterize_camera, rasterize_projected
from .camera_render import CameraRender
from .projection import Projection, covariance_3d, project_gaussians, quat_to_rotmat
from .reference import rasterize_dense
from .rolling_shutter import CameraMotion, ShutterTiming

__all__ = [
    "CameraMotion",
    "CameraRender",
    "LidarRender",
    "rasterize_lidar",
    "Projection",
    "covariance_3d",
    "project_gaussians",
    "quat_to_rotmat",
    "rasterize_camera",
    "rasterize_dense",
    "rasterize_projected",
    "ShutterTiming",
]
