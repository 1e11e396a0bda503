"""Rendering a batch of lidar rays of one sweep from the posed scene, with rolling-sweep time bins.

A sweep's rays are fired over ~0.1 s from a moving sensor while instances move. The rays of a
batch are split into K equal-width bins of their timestamps; for each bin the Gaussians are posed
at the bin's centre time (all bins in one call, :meth:`SceneModel.posed_gaussians_at_times`) and the sensor
is placed at the mean origin of the bin's rays with the sweep's rotation. Rays of different lidars
(Waymo's five sit up to ~2 m apart) are binned apart, so each lidar is rendered from its own
position. All (lidar, bin) groups are rendered by one :func:`~idsplat_ns.render.rasterize_lidar`
call with per-bin Gaussians (the set of present Gaussians may differ between bins: an instance may
appear or vanish mid-sweep), each group's Gaussians moved by the offset between its lidar position
and the first group's, so that one sensor pose serves every group (one rasterization instead of
one per group: a fixed cost per call dominates on a GPU).

Approximations (documented sizes):

* **Time**: every ray of a bin sees the scene at the bin's centre time. A ray is at most half a
  bin width away: with a 0.1 s sweep and K = 4 bins that is 12.5 ms, i.e. 12.5 cm for an object
  moving at 10 m/s (relative to the sensor).
* **Origin**: every ray of a bin is cast from the bin's mean origin ``c`` instead of its own origin
  ``o``, parallel to its own world direction ``d``. The along-ray part of the offset is corrected
  exactly: the returned ranges are ``r_c - (o - c) . d`` (range from the ray's own origin). The
  lateral part ``|(o - c) x d|`` is not: the rendered ray passes at most that far beside the true
  one. For a sensor at 10 m/s, a 0.1 s sweep and K = 4, rays of a bin are fired within 25 ms of
  each other, so the lateral offset is at most 12.5 cm (~0.25 m x 0.5); on a surface seen at
  incidence angle ``a`` that moves the hit range by up to ``0.125 * tan(a)`` metres.
* Direction: the ray's angles are its world direction in the sweep's rotation frame, exact (the
  sensor rotation over the sweep is carried by the per-ray world directions themselves).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
import torch
from torch import Tensor
from torch.nn.utils.rnn import pad_sequence

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.errors import IDSplatError
from idsplat_ns.render import LidarRender, rasterize_lidar
from idsplat_ns.render.lidar import cull_margin, seen_by_rays
from idsplat_ns.render.reference import ALPHA_MIN


@dataclass
class LidarRayBatch:
    """A subset of one sweep's rays as torch tensors (R rays, world frame)."""

    origins: Tensor  # [R, 3] float32 sensor position when each ray was fired
    directions: Tensor  # [R, 3] float32 unit directions
    ranges: Tensor  # [R] float32 metres from the ray's origin; 0 where nothing returned
    intensities: Tensor  # [R] float32 in [0, 1]; 0 where nothing returned
    times: Tensor  # [R] float64 seconds since the sequence start
    returned: Tensor  # [R] bool, False for rays that returned nothing
    sensor_ids: Optional[Tensor] = None  # [R] int64 which lidar fired each ray (None: one lidar)
    # CPU copies of ``times`` and ``sensor_ids`` (``sample_rays`` keeps them): the rays' groups are
    # made from them without reading the device. A batch whose times or lidars are replaced must
    # replace or drop these too.
    host_times: Optional[Tensor] = None  # [R] float64
    host_sensor_ids: Optional[Tensor] = None  # [R] int64

    @property
    def num_rays(self) -> int:
        return self.origins.shape[0]

    def to(self, device: torch.device | str) -> LidarRayBatch:
        moved = [getattr(self, f).to(device) for f in ("origins", "directions", "ranges", "intensities", "times", "returned")]
        return LidarRayBatch(*moved, sensor_ids=None if self.sensor_ids is None else self.sensor_ids.to(device),
                             host_times=self.host_times, host_sensor_ids=self.host_sensor_ids)


def sample_rays(
    sweep: LidarSweep,
    num_rays: int,
    generator: torch.Generator | None = None,
    device: torch.device | str = "cpu",
) -> LidarRayBatch:
    """``num_rays`` rays of ``sweep`` drawn uniformly without replacement (returned or not).

    All rays when the sweep has fewer. The chosen rays keep the sweep's order (sorted indices).
    """
    n = sweep.num_rays
    if n == 0:
        raise IDSplatError(
            f"sample_rays: lidar sweep of frame {sweep.frame_index} has no rays; drop it from the lidar frames"
        )
    if num_rays >= n:
        idx = np.arange(n)
    else:
        idx = torch.randperm(n, generator=generator)[:num_rays].sort().values.numpy()
    host_times = torch.as_tensor(sweep.times[idx], dtype=torch.float64)
    host_sensor_ids = torch.as_tensor(sweep.sensor_ids[idx].astype(np.int64))
    return LidarRayBatch(
        origins=torch.as_tensor(sweep.origins[idx], dtype=torch.float32, device=device),
        directions=torch.as_tensor(
            sweep.directions[idx], dtype=torch.float32, device=device
        ),
        ranges=torch.as_tensor(sweep.ranges[idx], dtype=torch.float32, device=device),
        intensities=torch.as_tensor(
            sweep.intensities[idx], dtype=torch.float32, device=device
        ),
        times=host_times.to(device),
        returned=torch.as_tensor(sweep.returned[idx], dtype=torch.bool, device=device),
        sensor_ids=host_sensor_ids.to(device),
        host_times=host_times,
        host_sensor_ids=host_sensor_ids,
    )


def time_bins(
    times: Tensor, num_bins: int
) -> tuple[Tensor, Tensor]:  # times: [R] float64
    """Equal-width bins over ``[min, max]`` of ``times``: bin index [R] int64 and centres [K] float64.

    One bin when all times are equal (or ``num_bins`` is 1).
    """
    if num_bins < 1:
        raise IDSplatError(f"num_time_bins must be >= 1, got {num_bins}")
    t = times.detach().to(torch.float64)
    t0, t1 = float(t.min()), float(t.max())
    if num_bins == 1 or not t1 > t0:
        return torch.zeros_like(t, dtype=torch.int64), torch.tensor(
            [0.5 * (t0 + t1)], dtype=torch.float64
        )
    width = (t1 - t0) / num_bins
    bins = torch.floor((t - t0) / width).long().clamp(0, num_bins - 1)
    centres = t0 + (torch.arange(num_bins, dtype=torch.float64) + 0.5) * width
    return bins, centres


def ray_angles(
    directions: Tensor,  # [R, 3] world unit directions
    sensor_rotation: Tensor,  # [3, 3] sensor-to-world rotation
) -> tuple[Tensor, Tensor]:
    """(azimuth [R], elevation [R]) in radians in the rasterizer's convention.

    Sensor-frame direction ``s = R^T d``; azimuth ``atan2(s_y, s_x)``, elevation
    ``atan2(s_z, hypot(s_x, s_y))`` (see :mod:`idsplat_ns.render.lidar`).
    """
    s = directions @ sensor_rotation  # row-wise R^T d
    azimuth = torch.atan2(s[:, 1], s[:, 0])
    elevation = torch.atan2(s[:, 2], torch.hypot(s[:, 0], s[:, 1]))
    return azimuth, elevation


@dataclass
class PosedBins:
    """World-posed Gaussians at the K time bins of a ray batch, one row set for every bin (N rows):
    what changes with the time (means, orientations, presence) per bin, the rest shared."""

    means: Tensor  # [K, N, 3] world
    quats: Tensor  # [K, N, 4] wxyz
    opacities: Tensor  # [K, N] activated; 0 where a Gaussian is absent at that bin's time
    scales: Tensor  # [N, 3] activated (metres)
    features: Tensor  # [N, D]


@dataclass
class _RayGroups:
    """The rays of a batch split into (lidar, time bin) groups, each cast from its own position."""

    centres: Tensor  # [K] float64 time-bin centres
    group_ids: Tensor  # [G] int64 sensor rank * K + bin of each group
    ray_group: Tensor  # [R] int64 group of each ray, 0..G-1
    origins: Tensor  # [G, 3] mean origin of each group's rays
    lidar_from_world: Tensor  # [4, 4] the sweep's rotation, placed at the first group's origin
    along: Tensor  # [R, 1] along-ray offset of each ray's own origin from its group's
    azimuth: Tensor  # [R] radians
    elevation: Tensor  # [R] radians


def _ray_groups(rays: LidarRayBatch, sensor_to_world: Tensor, num_time_bins: int) -> _RayGroups:
    if rays.num_rays == 0:
        raise IDSplatError("render_lidar_rays: the ray batch is empty; sample at least one ray")
    device = rays.origins.device
    # The grouping from the host copies where the batch has them (no device read), else on its device.
    host = rays.host_times is not None and len(rays.host_times) == rays.num_rays and (
        rays.sensor_ids is None or (rays.host_sensor_ids is not None and len(rays.host_sensor_ids) == rays.num_rays))
    times = rays.host_times if host else rays.times
    sensor_ids = None if rays.sensor_ids is None else (rays.host_sensor_ids if host else rays.sensor_ids)
    bins, centres = time_bins(times, num_time_bins)
    # One group per (lidar, time bin): each lidar is cast from its own position.
    if sensor_ids is not None:
        _, sensor_rank = torch.unique(sensor_ids.to(bins.device), return_inverse=True)
        groups = sensor_rank * centres.numel() + bins
    else:
        groups = bins
    group_ids, ray_group = torch.unique(groups, return_inverse=True)  # ray_group: [R] in 0..G-1
    num_groups = group_ids.numel()
    counts = torch.bincount(ray_group, minlength=num_groups)
    group_ids, ray_group = group_ids.to(device), ray_group.to(device)
    counts = counts.to(device=device, dtype=rays.origins.dtype)
    rot = sensor_to_world[:3, :3].to(device=device, dtype=torch.float32)
    # Each group's position: the mean origin of its rays.
    origins = torch.zeros(num_groups, 3, device=device, dtype=rays.origins.dtype).index_add_(0, ray_group, rays.origins)
    origins = origins / counts[:, None]
    lidar_from_world = torch.eye(4, device=device, dtype=torch.float32)
    lidar_from_world[:3, :3] = rot.T
    lidar_from_world[:3, 3] = -rot.T @ origins[0].float()
    # Range from each ray's own origin = range from its group's position minus this along-ray offset.
    along = ((rays.origins - origins[ray_group]) * rays.directions).sum(1, keepdim=True)
    az, el = ray_angles(rays.directions, rot)
    return _RayGroups(centres, group_ids, ray_group, origins, lidar_from_world, along, az, el)


def _rasterize_groups(
    means: Tensor,  # [G, M, 3] world, seen from the first group's position
    quats: Tensor,  # [G, M, 4]
    scales: Tensor,  # [M, 3] or [G, M, 3]
    opacities: Tensor,  # [G, M]
    features: Tensor,  # [M, D] or [G, M, D]
    groups: _RayGroups,
    cutoff_ranges: Optional[Tensor],  # [R] metres from each ray's own origin
    rasterizer_kwargs: dict,
) -> LidarRender:
    """One rasterization of every group's Gaussians, ranges measured from each ray's own origin
    instead of its group's (0 stays 0: no hit)."""
    along = groups.along
    cut = None if cutoff_ranges is None else cutoff_ranges + along[:, 0]
    out = rasterize_lidar(means, quats, scales, opacities, features,
                          groups.lidar_from_world.expand(groups.group_ids.numel(), 4, 4), groups.azimuth,
                          groups.elevation, ray_bins=groups.ray_group, ray_cutoff=cut, **rasterizer_kwargs)  # fmt: skip
    hit = out.alpha > 0
    return replace(
        out,
        range=torch.where(hit, out.range - along, out.range),
        median_range=torch.where(hit, out.median_range - along, out.median_range),
    )


def render_lidar_rays(
    posed_at: Callable[[float], dict],
    rays: LidarRayBatch,
    sensor_to_world: Tensor,  # [4, 4] sweep pose (its rotation is used; translation per bin)
    num_time_bins: int = 4,
    cutoff_ranges: Optional[Tensor] = None,  # [R] metres from each ray's own origin
    **rasterizer_kwargs,
) -> LidarRender:
    """Render ``rays``: per-ray features [R, D], alpha [R, 1], range and median range [R, 1].

    ``posed_at(t)`` returns world-posed activated Gaussians at time ``t`` (keys ``means``,
    ``quats``, ``scales``, ``opacities``, ``features``); the set may differ between times. Ranges
    are measured from each ray's own origin along its direction (first-order origin correction,
    see the module docstring); 0 where nothing was hit. With ``cutoff_ranges`` the render also has
    ``alpha_before_cutoff`` [R, 1]: the summed alphas of the Gaussians in front of each ray's
    cut-off (the line-of-sight loss). ``rasterizer_kwargs`` go to :func:`rasterize_lidar`
    (resolutions, planes...). The reference of :func:`render_lidar_rays_binned`, which poses the
    bins in one batch and is what training uses.
    """
    grp = _ray_groups(rays, sensor_to_world, num_time_bins)
    margin = None
    if rasterizer_kwargs.get("cull", True):
        margin = cull_margin(**{k: rasterizer_kwargs.get(k, _RASTERIZER_DEFAULTS[k]) for k in _GRID_ARGS})
    posed_cache: dict[int, dict] = {}
    per_group = []
    for g, group in enumerate(grp.group_ids.tolist()):
        b = int(group % grp.centres.numel())
        if b not in posed_cache:  # the Gaussians are posed once per time bin, shared by the lidars
            posed_cache[b] = posed_at(float(grp.centres[b]))
        posed = posed_cache[b]
        if g > 0:  # seen from the first group's position, the group's Gaussians sit moved by this offset
            posed = dict(posed, means=posed["means"] + (grp.origins[0] - grp.origins[g]).to(posed["means"].dtype))
        if margin is not None and posed["means"].shape[0]:
            # Only what the group's rays may reach is stacked (a time bin is a sector of a sweep):
            # memory in proportion to the Gaussians seen, not to groups x all Gaussians.
            mine = grp.ray_group == g
            seen = seen_by_rays(posed["means"].detach()[None], posed["scales"].detach(), grp.lidar_from_world[None],
                                grp.azimuth[mine].detach(), grp.elevation[mine].detach(),
                                torch.zeros_like(grp.ray_group[mine]), margin)[0]  # fmt: skip
            keep = torch.nonzero(seen & (posed["opacities"].detach() > ALPHA_MIN)).squeeze(1)
            posed = {k: posed[k].index_select(0, keep) for k in _GAUSSIAN_KEYS}
        per_group.append(posed)
    # Culled above, group by group (or culling is off): the rasterizer need not test again.
    g = _stack_groups(per_group)
    return _rasterize_groups(g["means"], g["quats"], g["scales"], g["opacities"], g["features"], grp, cutoff_ranges,
                             dict(rasterizer_kwargs, cull=False))  # fmt: skip


def render_lidar_rays_binned(
    posed_at_times: Callable[[Tensor], PosedBins],
    rays: LidarRayBatch,
    sensor_to_world: Tensor,  # [4, 4] sweep pose (its rotation is used; translation per bin)
    num_time_bins: int = 4,
    cutoff_ranges: Optional[Tensor] = None,  # [R] metres from each ray's own origin
    **rasterizer_kwargs,
) -> LidarRender:
    """:func:`render_lidar_rays` with the Gaussians of all time bins posed by one call,
    ``posed_at_times(centres [K]) -> PosedBins``, and culled and gathered for all (lidar, bin)
    groups at once by :func:`rasterize_lidar`: a fixed number of operations whatever the number
    of bins and lidars, where the reference loops over them. The same render: each group keeps
    the same Gaussians in the same order."""
    grp = _ray_groups(rays, sensor_to_world, num_time_bins)
    posed = posed_at_times(grp.centres.to(rays.origins.device))
    bin_of = grp.group_ids % grp.centres.numel()  # [G] time bin of each group
    shift = (grp.origins[:1] - grp.origins).to(posed.means.dtype)  # [G, 3]; seen from group 0's position
    # The rasterizer culls each group by its own rays and gathers the kept Gaussians of every group
    # at once (rasterize_lidar with per-bin means and opacities, shared scales and features).
    return _rasterize_groups(posed.means.index_select(0, bin_of) + shift[:, None], posed.quats.index_select(0, bin_of),
                             posed.scales, posed.opacities.index_select(0, bin_of), posed.features, grp, cutoff_ranges,
                             rasterizer_kwargs)  # fmt: skip


_GAUSSIAN_KEYS = ("means", "quats", "scales", "opacities", "features")
_GRID_ARGS = ("azimuth_resolution", "elevation_resolution", "tile_size", "eps2d")
_RASTERIZER_DEFAULTS = {k: p.default for k, p in inspect.signature(rasterize_lidar).parameters.items()}


def _stack_groups(groups: list[dict]) -> dict[str, Tensor]:
    """The groups' posed Gaussians (``means`` [N_g, 3], ``quats``, ``scales``, ``opacities``,
    ``features``) stacked per bin, [G, max N_g, ...], the short ones padded with Gaussians of
    opacity 0 (which the rasterizer drops) and a valid rotation (quaternion (1, 1, 1, 1)), so that
    no padding row has an undefined covariance."""
    pad = {"means": 0.0, "quats": 1.0, "scales": 1.0, "opacities": 0.0, "features": 0.0}
    return {k: pad_sequence([g[k] for g in groups], batch_first=True, padding_value=v) for k, v in pad.items()}
