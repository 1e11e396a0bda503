"""Lidar rasterizer: Gaussians splatted in (azimuth, elevation) and composited per ray.

Each Gaussian is moved to the sensor frame and linearised in spherical coordinates: azimuth
``phi = atan2(y, x)``, elevation ``theta = atan2(z, sqrt(x^2 + y^2))``, with the Jacobian of that
map (SplatAD's formulation). Angles are measured in grid units of ``azimuth_resolution`` and
``elevation_resolution`` (radians); the low-pass ``eps2d`` is in those units, like pixels for a
camera. Rays are irregular (non-uniform beam elevations, per-point azimuths): each is evaluated at
its own angles. Rays are sorted into tiles of the angular grid and padded to the fullest tile,
then the camera's fused compositor does the rest. Azimuth is periodic: the grid has a whole
number of tiles around 360 degrees and angle differences are wrapped, so there is no seam at
+-180 degrees. Rays straight up or down are fine: near the poles a Gaussian's azimuth extent grows
to the full circle instead of dividing by zero.

Rolling sweep (time): **time bins**. The caller splits a sweep into K bins (e.g. by azimuth
column or by timestamp), poses the Gaussians for each bin's time (moving instances move; the
sensor pose may differ per bin) and passes ``means`` [K, N, 3], ``quats`` [K, N, 4] and
``lidar_from_world`` [K, 4, 4] with ``ray_bins`` [R] naming each ray's bin. Bins are composited
like separate cameras in one call. K = 1 (default) is a static sweep.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Optional

import torch
from torch import Tensor

from ..errors import IDSplatError
from .compositor import choose_compositor
from .projection import covariance_3d
from .reference import ALPHA_MIN
from .tile_composite import (
    CompositePlan, TileComposite, monomial_basis, quadratic_coefficients,
)  # fmt: skip
from .tiles import intersect_tiles, tile_centres


@dataclass
class LidarRender:
    """Per-ray outputs of :func:`rasterize_lidar` (R rays)."""

    features: Tensor  # [R, D] composited features (e.g. intensity, ray-drop logit)
    alpha: Tensor  # [R, 1] accumulated opacity
    range: Tensor  # [R, 1] expected range sum w r / alpha, 0 where alpha == 0
    median_range: Tensor  # [R, 1] range where transmittance crosses 0.5 (else expected range)
    alpha_before_cutoff: Optional[Tensor] = None  # [R, 1] sum of alphas in front of the ray's cut-off range

    @property
    def range_unnormalised(self) -> Tensor:  # [R, 1]
        """``sum_i w_i r_i`` = ``alpha * range``: the expected range without the division by
        alpha (SplatAD's rendered depth; 0 where nothing is hit, no 1/alpha in its gradient)."""
        return self.range * self.alpha


@dataclass
class SphericalProjection:
    """Gaussians in angular grid units (see :func:`project_spherical`)."""

    means2d: Tensor  # [K, N, 2] (azimuth, elevation) in grid units
    covars2d: Tensor  # [K, N, 3] blurred 2D covariance (xx, xy, yy)
    conics: Tensor  # [K, N, 3] its inverse (a, b, c)
    ranges: Tensor  # [K, N] distance to the sensor
    radii: Tensor  # [K, N] int32, 0 = culled


def _jacobian_sandwich(
    jac: tuple,  # rows of the sensor-frame 2x3 Jacobian: ((J00, J01), (J10, J11, J12)), each [K, N] (J02 = 0)
    rot: Tensor,  # [K, 3, 3] sensor-from-world rotation
    covars: Tensor,  # [K, N, 3, 3] world covariances
) -> list[list[Tensor]]:  # 2 x 2 of [K, N]
    """``J (R S R^T) J^T`` as ``(J R) S (J R)^T``, entry by entry on [K, N] planes: a batch of N
    3x3 products by ``bmm`` (the einsum form) took twice as long on the CPU, forward and backward.
    Every entry of ``S`` is read as given (no symmetry assumed), as the matrix form does."""
    r = [[rot[:, i, m][:, None] for m in range(3)] for i in range(3)]  # [K, 1] each
    j0 = [jac[0][0] * r[0][m] + jac[0][1] * r[1][m] for m in range(3)]  # (J R) row 0
    j1 = [jac[1][0] * r[0][m] + jac[1][1] * r[1][m] + jac[1][2] * r[2][m] for m in range(3)]
    jw = (j0, j1)
    # Nine contiguous planes in one copy (and one in the backward pass), not nine strided selects.
    flat = covars.flatten(-2).movedim(-1, 0).contiguous().unbind(0)
    s = [flat[3 * i : 3 * i + 3] for i in range(3)]
    # t[a][k] = sum_i (J R)[a, i] S[i, k]; entry (a, b) = sum_k t[a][k] (J R)[b, k]
    t = [[jw[a][0] * s[0][k] + jw[a][1] * s[1][k] + jw[a][2] * s[2][k] for k in range(3)] for a in range(2)]
    return [[t[a][0] * jw[b][0] + t[a][1] * jw[b][1] + t[a][2] * jw[b][2] for b in range(2)] for a in range(2)]


def project_spherical(
    means: Tensor,  # [K, N, 3] world
    covars: Tensor,  # [K, N, 3, 3] world
    lidar_from_world: Tensor,  # [K, 4, 4]
    azimuth_resolution: float,
    elevation_resolution: float,
    elevation_min: float,
    grid_height: int,
    *,
    eps2d: float = 0.3,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
) -> SphericalProjection:
    """EWA projection to the grid ``u = wrap(phi) / az_res``, ``v = (theta - el_min) / el_res``."""
    rot = lidar_from_world[:, :3, :3]
    p = torch.einsum("kij,knj->kni", rot, means) + lidar_from_world[:, None, :3, 3]
    x, y, z = p.unbind(-1)
    rho2 = x * x + y * y
    r = torch.sqrt(rho2 + z * z)
    phi = torch.atan2(y, x)
    ok = (r > near_plane) & (r < far_plane)
    r_safe = torch.where(ok, r, torch.ones_like(r))
    # Floor on the horizontal distance: at the poles azimuth is undefined; the floor makes the
    # azimuth variance huge (full circle) instead of infinite.
    floor = 1e-6 * r_safe
    at_pole = rho2 <= floor * floor
    # Exactly at a pole the azimuth direction is undefined; pretend the Gaussian sits `floor`
    # off the axis so that its azimuth extent becomes the full circle rather than zero.
    x = torch.where(at_pole, floor, x)
    y = torch.where(at_pole, torch.zeros_like(y), y)
    rho2_safe = torch.where(at_pole, floor * floor, rho2)
    rho = torch.sqrt(rho2_safe)
    theta = torch.atan2(z, rho)
    two_pi = 2.0 * math.pi
    width = two_pi / azimuth_resolution
    u = torch.remainder(phi, two_pi) / azimuth_resolution
    v = (theta - elevation_min) / elevation_resolution
    r2 = r_safe * r_safe
    # Jacobian of (u, v) in the sensor frame (its (0, 2) entry is 0).
    jac = ((-y / rho2_safe / azimuth_resolution, x / rho2_safe / azimuth_resolution),
           (-x * z / (r2 * rho) / elevation_resolution, -y * z / (r2 * rho) / elevation_resolution,
            rho / r2 / elevation_resolution))  # fmt: skip
    cov2d = _jacobian_sandwich(jac, rot, covars)
    c_xx = cov2d[0][0] + eps2d
    c_xy = 0.5 * (cov2d[0][1] + cov2d[1][0])
    c_yy = cov2d[1][1] + eps2d
    det = (c_xx * c_yy - c_xy * c_xy).clamp_min(1e-10)
    conics = torch.stack([c_yy / det, -c_xy / det, c_xx / det], dim=-1)
    with torch.no_grad():
        b = 0.5 * (c_xx + c_yy)
        radius = torch.ceil(3.0 * torch.sqrt(b + torch.sqrt(torch.clamp(b * b - det, min=0.01))))
        radius = torch.nan_to_num(radius, nan=0.0, posinf=1e7).clamp(max=1e7)
        inside = (v + radius > 0) & (v - radius < grid_height)
        radii = torch.where(ok & inside, radius, torch.zeros_like(radius)).to(torch.int32)
    # Keep u inside [0, width) even after rounding (remainder can return width itself).
    u = torch.where(u >= width, u - width, u)
    return SphericalProjection(
        means2d=torch.stack([u, v], dim=-1),
        covars2d=torch.stack([c_xx, c_xy, c_yy], dim=-1),
        conics=conics,
        ranges=torch.where(ok, r, torch.zeros_like(r)),
        radii=radii,
    )


_CULL_BUCKETS = 360  # azimuth buckets of the ray-coverage test (1 degree)


@torch.no_grad()
def seen_by_rays(
    means: Tensor,  # [K, N, 3] world
    scales: Tensor,  # [N, 3] or [K, N, 3]
    lidar_from_world: Tensor,  # [K, 4, 4]
    ray_azimuth: Tensor,  # [R] radians
    ray_elevation: Tensor,  # [R] radians
    ray_bins: Tensor,  # [R] int64
    margin: float,  # radians added to every Gaussian's angular extent
) -> Tensor:  # [K, N] bool
    """Which Gaussian of each bin may reach a ray of that bin (conservative angular test; used to cull).

    A Gaussian spans at most the cone ``asin(3 max_scale / range)`` around its mean's direction
    (its 3-sigma sphere), widened by ``margin`` (the low-pass and the tile padding). It is kept when
    that cone meets the rays' elevation band and a 1-degree azimuth bucket holding a ray of the same
    bin (azimuth half-width ``asin(sin(cone) / cos(elevation))``). A time bin of a spinning lidar
    covers a sector, so most Gaussians are culled per bin.
    """
    k = means.shape[0]
    p = torch.einsum("kij,knj->kni", lidar_from_world[:, :3, :3], means) + lidar_from_world[:, None, :3, 3]
    r = p.norm(dim=-1)
    max_scale = scales.max(dim=-1).values.expand(r.shape)
    ext = torch.asin((3.0 * max_scale / r.clamp_min(1e-9)).clamp(max=1.0)) + margin
    phi = torch.remainder(torch.atan2(p[..., 1], p[..., 0]), 2 * math.pi)
    theta = torch.atan2(p[..., 2], torch.hypot(p[..., 0], p[..., 1]))
    # A cone of half-angle ext around elevation theta spans azimuths +-asin(sin(ext) / cos(theta)),
    # the whole circle once it reaches a pole.
    az_ext = torch.asin((torch.sin(ext.clamp(max=math.pi / 2)) / torch.cos(theta).clamp_min(1e-9)).clamp(max=1.0))
    az_ext = torch.where(theta.abs() + ext >= math.pi / 2, torch.full_like(az_ext, math.pi), az_ext)
    width = 2 * math.pi / _CULL_BUCKETS
    bucket = (torch.remainder(ray_azimuth.to(p.dtype), 2 * math.pi) / width).long().clamp(0, _CULL_BUCKETS - 1)
    occupied = torch.zeros(k, _CULL_BUCKETS, device=p.device, dtype=torch.int64)
    occupied[ray_bins, bucket] = 1
    # Prefix sums over three laps of the circle answer wrapped interval queries directly.
    csum = torch.cat([occupied.new_zeros(k, 1), torch.cumsum(occupied.repeat(1, 3), dim=1)], dim=1)  # [K, 3B + 1]
    lo = (torch.floor((phi - az_ext) / width).long() + _CULL_BUCKETS).clamp(0, 3 * _CULL_BUCKETS - 1)
    hi = (torch.floor((phi + az_ext) / width).long() + _CULL_BUCKETS).clamp(0, 3 * _CULL_BUCKETS - 1)
    in_azimuth = (torch.gather(csum, 1, hi + 1) - torch.gather(csum, 1, lo) > 0)
    el = ray_elevation.to(p.dtype)
    el_lo = torch.full((k,), math.inf, device=p.device, dtype=p.dtype).scatter_reduce(0, ray_bins, el, "amin")
    el_hi = torch.full((k,), -math.inf, device=p.device, dtype=p.dtype).scatter_reduce(0, ray_bins, el, "amax")
    in_elevation = (theta + ext >= el_lo[:, None]) & (theta - ext <= el_hi[:, None])
    return in_azimuth & in_elevation


def azimuth_grid(azimuth_resolution: float, tile_size: int) -> tuple[int, int, float]:
    """Tiles around the circle, grid width in cells, and the cell's azimuth (radians): a whole
    number of tiles of about ``azimuth_resolution`` cells."""
    tiles_x = max(1, round(2 * math.pi / azimuth_resolution / tile_size))
    width = tiles_x * tile_size
    return tiles_x, width, 2 * math.pi / width


def cull_margin(azimuth_resolution: float, elevation_resolution: float, tile_size: int = 8, eps2d: float = 0.3) -> float:
    """Radians added to a Gaussian's extent by :func:`seen_by_rays` in :func:`rasterize_lidar`:
    a tile and the low-pass's 3 sigma, in the coarser of the two grid directions."""
    az_res = azimuth_grid(azimuth_resolution, tile_size)[2]
    return (tile_size + 3.0 * math.sqrt(eps2d) + 1.0) * max(az_res, elevation_resolution)


def kept_per_bin(keep: Tensor) -> tuple[Tensor, Tensor]:  # keep: [K, N] bool
    """The kept Gaussians of each bin in their order, padded to the fullest bin: index [K, M]
    int64 and valid [K, M] bool (False for the padding, whose index is that of a dropped one)."""
    counts = keep.sum(dim=1)
    m = int(counts.max()) if keep.numel() else 0
    index = torch.sort((~keep).to(torch.uint8), dim=1, stable=True).indices[:, :m]
    valid = torch.arange(m, device=keep.device)[None] < counts[:, None]
    return index, valid


# Cost of a composited row in units of one sample slot: a row's coefficients, gathers and small
# matrix products are paid whatever the slot count. Calibrated on the CPU: training batches of the
# demo street were fastest with 4-8 slots (1 slot: 1.9x, the fullest tile: 1.3x), which 8 picks.
_ROW_OVERHEAD_SLOTS = 8.0


@torch.no_grad()
def sub_tile_slots(per_tile: Tensor, pairs: Tensor, max_slots: int = 64) -> int:  # per_tile, pairs: [T] int64
    """Rays per sub-tile: the count S that minimises the compositor's work,
    ``sum_t pairs_t * ceil(rays_t / S) * (S + overhead)`` over tiles with rays (at most
    ``max_slots`` candidates, and never more than the fullest tile)."""
    has = per_tile > 0
    if not bool(has.any()):
        return 1
    rays, rows = per_tile[has].to(torch.float64), pairs[has].to(torch.float64)
    top = min(max_slots, int(rays.max()))
    cand = torch.arange(1, top + 1, device=per_tile.device, dtype=torch.float64)
    cost = (rows[None] * torch.ceil(rays[None] / cand[:, None])).sum(1) * (cand + _ROW_OVERHEAD_SLOTS)
    return int(cand[int(torch.argmin(cost))])


@torch.no_grad()
def split_tiles(
    per_tile: Tensor,  # [T] int64 rays per tile
    tile_offsets: Tensor,  # [T + 1] int64 start of each tile's run of intersections
    slots: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """Sub-tiles of at most ``slots`` rays, tiles in order, ``ceil(rays / slots)`` each (none for a
    tile without rays): each tile's first sub-tile [T], the sub-tiles' run offsets [V + 1] and, for
    every row of those runs, the intersection row of the tile that it copies [I']."""
    device = per_tile.device
    subs = torch.div(per_tile + slots - 1, slots, rounding_mode="floor")
    tile_of = torch.repeat_interleave(torch.arange(per_tile.numel(), device=device), subs)
    runs = (tile_offsets[1:] - tile_offsets[:-1]).index_select(0, tile_of)
    offsets = torch.zeros(tile_of.numel() + 1, dtype=torch.int64, device=device)
    offsets[1:] = torch.cumsum(runs, 0)
    total = int(offsets[-1])
    owner = torch.repeat_interleave(torch.arange(tile_of.numel(), device=device), runs, output_size=total)
    src = tile_offsets[:-1].index_select(0, tile_of).index_select(0, owner) + (
        torch.arange(total, device=device) - offsets[:-1].index_select(0, owner)
    )
    return torch.cumsum(subs, 0) - subs, offsets, src


def _take(x: Tensor, index: Tensor, per_bin: bool) -> Tensor:
    """``x`` [N, ...] (shared by the bins) or [K, N, ...] (per bin) at ``index`` [K, M]: [K, M, ...]."""
    k, m = index.shape
    if per_bin:  # rows of bin b start at b * N in the flattened tensor
        index = index + torch.arange(k, device=index.device)[:, None] * x.shape[1]
        x = x.reshape((-1,) + x.shape[2:])
    return x.index_select(0, index.reshape(-1)).reshape((k, m) + x.shape[1:])


def rasterize_lidar(
    means: Tensor,  # [N, 3] or [K, N, 3] world positions (per time bin)
    quats: Tensor,  # [N, 4] or [K, N, 4] wxyz
    scales: Tensor,  # [N, 3], or [K, N, 3] per bin
    opacities: Tensor,  # [N], or [K, N] per bin
    features: Tensor,  # [N, D], or [K, N, D] per bin
    lidar_from_world: Tensor,  # [4, 4] or [K, 4, 4]
    ray_azimuth: Tensor,  # [R] radians, any range (wrapped)
    ray_elevation: Tensor,  # [R] radians in [-pi/2, pi/2]
    *,
    ray_bins: Optional[Tensor] = None,  # [R] int64 time bin of each ray (required when K > 1)
    azimuth_resolution: float = math.radians(0.2),
    elevation_resolution: float = math.radians(0.2),
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    tile_size: int = 8,
    chunk_elems: Optional[int] = None,  # compositor block size (None: the device's default)
    ray_cutoff: Optional[Tensor] = None,  # [R] metres from the sensor origin (line of sight)
    cull: bool = True,
    compositor: str = "auto",  # "compiled" (numba, CPU), "triton" (CUDA), "torch" (tensor ops) or "auto"
) -> LidarRender:
    """Render lidar rays: expected/median range, features and alpha per ray (differentiable).

    The azimuth grid is rounded to a whole number of tiles (``tile_size`` cells of about
    ``azimuth_resolution``). See the module docstring for the time-bin convention.

    With ``ray_cutoff``, ``alpha_before_cutoff`` [R, 1] is the sum of the alphas of the Gaussians
    that the ray composites (alpha >= 1/255, before the transmittance is used up) whose range is
    below the ray's cut-off (SplatAD's ``alpha_sum_until_points``; differentiable in the alphas,
    the range test itself is a step). Without it the compositor does no extra work.

    ``cull``: project only the Gaussians that :func:`seen_by_rays` keeps, and of each bin only
    those its own rays may reach (same output, less work). Gaussians with an opacity at or below
    1/255 are dropped either way: they can never reach the compositor's alpha threshold.

    ``compositor``: ``"compiled"`` (numba loops, CPU tensors), ``"triton"`` (Triton kernels, float32
    CUDA tensors), ``"torch"`` (tensor ops, any device) or ``"auto"`` (compiled on the CPU, Triton
    on CUDA where it is installed); the same result to float rounding.

    Scales, opacities and features are each shared by the bins ([N, ...]) or given per bin ([K, N,
    ...]): per bin, each bin is its own set of Gaussians (padding with opacity 0 is dropped), so bins
    whose Gaussians differ (instances present in one bin only) are rendered in one call; per-bin
    opacities with shared scales and features are one row set posed at K times.
    """
    if means.dim() == 2:
        means, quats = means[None], quats[None]
    if lidar_from_world.dim() == 2:
        lidar_from_world = lidar_from_world[None]
    k, n = means.shape[:2]
    if quats.shape != (k, n, 4) or lidar_from_world.shape != (k, 4, 4):
        raise IDSplatError(
            f"rasterize_lidar: means {tuple(means.shape)}, quats {tuple(quats.shape)} and "
            f"lidar_from_world {tuple(lidar_from_world.shape)} must share the bin count K"
        )
    # Each of scales, opacities and features is shared by the bins ([N, ...]) or given per bin.
    scales_per_bin, opacities_per_bin, features_per_bin = scales.dim() == 3, opacities.dim() == 2, features.dim() == 3
    per_bin = scales_per_bin or opacities_per_bin or features_per_bin
    if (scales.shape[-1:] != (3,) or scales.shape[:-1] != ((k, n) if scales_per_bin else (n,))
            or opacities.shape != ((k, n) if opacities_per_bin else (n,))
            or features.shape[:-1] != ((k, n) if features_per_bin else (n,)) or features.dim() not in (2, 3)):
        raise IDSplatError(
            f"rasterize_lidar: scales {tuple(scales.shape)}, opacities {tuple(opacities.shape)} and features "
            f"{tuple(features.shape)} must each be per Gaussian [N, ...] or per bin [K, N, ...] with K={k}, N={n}"
        )
    if k > 1 and ray_bins is None:
        raise IDSplatError("rasterize_lidar: ray_bins is required when Gaussians are given for K > 1 time bins")
    if ray_azimuth.shape != ray_elevation.shape or ray_azimuth.dim() != 1:
        raise IDSplatError("rasterize_lidar: ray_azimuth and ray_elevation must both be [R]")
    device, dtype = means.device, means.dtype
    if ray_bins is None:
        ray_bins = torch.zeros_like(ray_azimuth, dtype=torch.int64)

    # Angular grid: whole tiles around the circle; rows spanning the rays' elevations.
    tiles_x, width, az_res = azimuth_grid(azimuth_resolution, tile_size)
    keep = (opacities.detach() > ALPHA_MIN).expand(k, n)
    if cull and n > 0 and ray_azimuth.numel() > 0:
        margin = cull_margin(azimuth_resolution, elevation_resolution, tile_size, eps2d)
        keep = keep & seen_by_rays(means.detach(), scales.detach(), lidar_from_world.detach(), ray_azimuth.detach(),
                                   ray_elevation.detach(), ray_bins, margin)  # fmt: skip
    if not bool(keep.any()):  # no Gaussian that can reach any ray: nothing is hit
        zeros = means.new_zeros(ray_azimuth.shape[0], 1)
        return LidarRender(features=features.new_zeros(ray_azimuth.shape[0], features.shape[-1]), alpha=zeros,
                           range=zeros, median_range=zeros, alpha_before_cutoff=None if ray_cutoff is None else zeros)
    if k == 1 and not per_bin:  # one bin: a plain selection, no padding
        index = torch.nonzero(keep[0]).squeeze(1)
        if index.numel() < n:
            means, quats, scales = means.index_select(1, index), quats.index_select(1, index), scales.index_select(0, index)
            opacities, features, n = opacities.index_select(0, index), features.index_select(0, index), index.numel()
        scales, opacities, features = scales[None], opacities[None], features[None]
    else:
        index, valid = kept_per_bin(keep)
        means, quats = _take(means, index, True), _take(quats, index, True)
        scales, features = _take(scales, index, scales_per_bin), _take(features, index, features_per_bin)
        opacities = torch.where(valid, _take(opacities, index, opacities_per_bin), 0.0)  # padding: never composited
        n = index.shape[1]
    el = ray_elevation.detach()
    el_min = float(el.min()) - 2 * elevation_resolution if el.numel() else 0.0
    el_max = float(el.max()) + 2 * elevation_resolution if el.numel() else 0.0
    height = max(1, math.ceil((el_max - el_min) / elevation_resolution))
    tiles_y = math.ceil(height / tile_size)
    height = tiles_y * tile_size

    proj = project_spherical(
        means, covariance_3d(quats.reshape(-1, 4), scales.reshape(-1, 3)).reshape(k, n, 3, 3),
        lidar_from_world, az_res, elevation_resolution, el_min, height,
        eps2d=eps2d, near_plane=near_plane, far_plane=far_plane,
    )  # fmt: skip
    isects = intersect_tiles(
        proj.means2d.detach(), proj.covars2d.detach(), proj.ranges.detach(), proj.radii,
        opacities.detach(), width, height, tile_size, wrap_x=True, samples_anywhere=True,
    )  # fmt: skip

    # Rays into tiles and their rank inside the tile.
    ru = torch.remainder(ray_azimuth.detach().to(dtype), 2 * math.pi) / az_res
    ru = torch.where(ru >= width, ru - width, ru)
    rv = (ray_elevation.detach().to(dtype) - el_min) / elevation_resolution
    col = torch.div(ru, tile_size, rounding_mode="floor").long().clamp(0, tiles_x - 1)
    row = torch.div(rv, tile_size, rounding_mode="floor").long().clamp(0, tiles_y - 1)
    ray_tile = ray_bins * (tiles_x * tiles_y) + row * tiles_x + col
    num_tiles = k * tiles_x * tiles_y
    _, order = torch.sort(ray_tile, stable=True)
    per_tile = torch.bincount(ray_tile, minlength=num_tiles)
    start = torch.cumsum(per_tile, 0) - per_tile
    rank = torch.empty_like(order)
    rank[order] = torch.arange(order.numel(), device=device) - start[ray_tile[order]]
    # Only tiles with rays are composited: a sparse training batch, or one time bin of a spinning
    # lidar (a sector of the circle), leaves most tiles of the grid empty.
    in_use = (per_tile > 0)[isects.tile_ids]
    if not bool(in_use.all()):
        kept_tiles = isects.tile_ids[in_use]
        offsets = torch.zeros(num_tiles + 1, dtype=torch.int64, device=device)
        offsets[1:] = torch.cumsum(torch.bincount(kept_tiles, minlength=num_tiles), 0)
        isects = replace(isects, gaussian_ids=isects.gaussian_ids[in_use], tile_ids=kept_tiles, tile_offsets=offsets)
    # Rays are irregular: a few tiles hold many, most a few. Padding every tile to the fullest
    # would composite mostly padding, so a tile's rays are dealt into sub-tiles of `slots` rays,
    # each with the tile's Gaussian list (tiles without rays get none).
    pairs = isects.tile_offsets[1:] - isects.tile_offsets[:-1]
    slots = sub_tile_slots(per_tile, pairs)
    first_sub, sub_offsets, src = split_tiles(per_tile, isects.tile_offsets, slots)
    ray_sub = first_sub[ray_tile] + torch.div(rank, slots, rounding_mode="floor")
    slot = rank % slots
    num_sub = sub_offsets.numel() - 1
    # Sample offsets from the tile centre (0 for padding slots, which are masked out).
    f64 = torch.float64
    tile_cx, tile_cy = tile_centres(torch.arange(num_tiles, device=device), tiles_x, tiles_y, tile_size)
    ex = torch.zeros(num_sub, slots, device=device, dtype=f64)
    ey = torch.zeros(num_sub, slots, device=device, dtype=f64)
    slot_valid = torch.zeros(num_sub, slots, device=device, dtype=dtype)
    ex[ray_sub, slot] = ru - tile_cx[ray_tile]  # sample at the ray's own angles (no +0.5)
    ey[ray_sub, slot] = rv - tile_cy[ray_tile]
    slot_valid[ray_sub, slot] = 1.0

    flat_range = proj.ranges.reshape(-1)
    feats = torch.cat(
        [features.reshape(k * n, -1), flat_range[:, None], torch.ones_like(flat_range[:, None])], dim=1
    )
    gid = isects.gaussian_ids
    # index_select, not x[gid]: its backward is one index_add; advanced indexing's backward is an
    # accumulating index_put, which CUDA runs as a sort of the millions of intersection rows.
    m = proj.means2d.reshape(-1, 2).index_select(0, gid)
    dxc = m[:, 0].to(f64) - tile_cx[isects.tile_ids]
    dxc = dxc - width * torch.round(dxc.detach() / width)  # azimuth wraps: nearest copy of the mean
    coeffs = quadratic_coefficients(
        dxc, m[:, 1].to(f64) - tile_cy[isects.tile_ids], proj.conics.reshape(-1, 3).index_select(0, gid),
        opacities.reshape(-1).index_select(0, gid),
    )  # fmt: skip
    gid, coeffs = gid.index_select(0, src), coeffs.index_select(0, src)  # each sub-tile's copy of its list
    cutoff = None
    if ray_cutoff is not None:
        # Padding slots get -inf: no Gaussian is in front of them.
        cutoff = torch.full((num_sub, slots), -math.inf, device=device, dtype=dtype)
        cutoff[ray_sub, slot] = ray_cutoff.detach().to(dtype)
    plan = CompositePlan(
        tile_offsets=sub_offsets, gaussian_ids=gid, basis=monomial_basis(ex, ey),
        slot_valid=slot_valid, block_elems=chunk_elems,
        cutoff_depths=cutoff, gaussian_depths=None if cutoff is None else flat_range.detach(),
    )  # fmt: skip
    kind = choose_compositor(compositor, feats)
    if kind == "compiled":
        from .compiled_composite import CompiledTileComposite  # numba only when it runs

        composited = CompiledTileComposite.apply(coeffs, feats, plan)
    elif kind == "triton":
        from .triton_composite import TritonTileComposite  # Triton only when it runs

        composited = TritonTileComposite.apply(coeffs, feats, plan)
    else:
        composited = TileComposite.apply(coeffs, feats, plan)
    pix, crossing = composited[0], composited[1]
    flat_slot = ray_sub * slots + slot
    before_cutoff = composited[2].reshape(-1).index_select(0, flat_slot)[:, None] if cutoff is not None else None
    out = pix.index_select(0, flat_slot)  # [R, D + 2]
    d = features.shape[-1]
    alpha = out[:, d + 1 : d + 2]
    has = alpha > 0
    expected = torch.where(has, out[:, d : d + 1] / torch.where(has, alpha, torch.ones_like(alpha)), 0.0)
    # Median: the crossing-th Gaussian of the ray's list, when the ray crosses T = 0.5.
    counts = sub_offsets[1:] - sub_offsets[:-1]
    cross = crossing.reshape(-1)[flat_slot]
    found = cross < counts[ray_sub]
    row_idx = (sub_offsets[:-1][ray_sub] + cross).clamp_max(max(gid.numel() - 1, 0))
    med = flat_range[gid[row_idx]] if gid.numel() else torch.zeros_like(cross, dtype=dtype)
    median = torch.where(found[:, None], med[:, None], expected)
    return LidarRender(features=out[:, :d], alpha=alpha, range=expected, median_range=median,
                       alpha_before_cutoff=before_cutoff)  # fmt: skip
