"""Lidar supervision of a :class:`~idsplat_ns.model.scene_model.SceneModel`: a batch of rays from
one training sweep per (k-th) step, rendered at the rays' own times and turned into the paper's
lidar losses; and whole-sweep renders with the Table-2 metrics for evaluation (the ray-drop
accuracy only where the data marks rays without a return).

Batches: each lidar step draws one training sweep uniformly and ``rays_per_step`` of its rays
uniformly (returned or not). One sweep per step keeps the time bins narrow (a sweep spans ~0.1 s)
so the Gaussians are posed ``num_time_bins`` times, not once per ray time across the sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Optional

import numpy as np
import torch
from torch import Tensor

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.scene import Scene
from idsplat_ns.model.lidar_losses import LidarLossConfig, lidar_losses
from idsplat_ns.model.lidar_render import LidarRayBatch, sample_rays
from idsplat_ns.ranges import AT_LEAST_ONE, OPEN_UNIT, POSITIVE, bounded


@dataclass
class LidarConfig:
    """Lidar path settings (paper / SplatAD defaults where the paper has them)."""

    enabled: bool = True
    """Supervise with lidar when the scene has lidar (False: camera-only, no lidar head)."""
    rays_per_step: int = bounded(16384, AT_LEAST_ONE)
    """Rays drawn from one training sweep per lidar step (the loss is a mean over them). On the CPU
    the cost of a lidar step hardly depends on it (posing and projecting the Gaussians dominate)."""
    every_n_steps: int = bounded(1, AT_LEAST_ONE)
    """Lidar step cadence: every n-th training step (paper: every step)."""
    num_time_bins: int = bounded(4, AT_LEAST_ONE)
    """Time bins per rendered sweep: instances are posed at each bin's centre time."""
    losses: LidarLossConfig = field(default_factory=LidarLossConfig)
    """Loss weights, line-of-sight margin and depth quantile."""
    head_hidden: int = bounded(32, AT_LEAST_ONE)
    """Hidden width of the 2-layer lidar head (paper: 32)."""
    azimuth_resolution_deg: float = bounded(0.2, POSITIVE)
    """Angular grid cell of the lidar rasterizer in azimuth (degrees)."""
    elevation_resolution_deg: float = bounded(0.2, POSITIVE)
    """Angular grid cell of the lidar rasterizer in elevation (degrees)."""
    near_plane: float = 0.2
    """Gaussians nearer than this to the sensor (metres) are not rendered (SplatAD: 0.2)."""
    far_plane: float = bounded(300.0, POSITIVE)
    """Gaussians farther than this (metres) are not rendered (SplatAD: 300)."""
    eval_max_rays_per_sweep: Optional[int] = None
    """Evaluate on at most this many rays of each held-out sweep (None: every ray)."""
    drop_threshold: float = bounded(0.5, OPEN_UNIT)
    """A ray is predicted dropped when its ray-drop probability is at least this (metrics, point cloud)."""
    compositor: Literal["auto", "compiled", "torch", "triton"] = "auto"
    """Lidar tile compositor: ``auto`` (compiled loops on the CPU, Triton kernels on CUDA where Triton
    is installed, else torch), ``compiled`` (CPU), ``triton`` (CUDA) or ``torch`` (tensor ops, any
    device). The rays render the same up to float rounding."""

    def rasterizer_kwargs(self) -> dict:
        return {
            "azimuth_resolution": math.radians(self.azimuth_resolution_deg),
            "elevation_resolution": math.radians(self.elevation_resolution_deg),
            "near_plane": self.near_plane,
            "far_plane": self.far_plane,
            "compositor": self.compositor,
        }


def sweeps_of_frames(scene: Scene, frames: set[int]) -> list[LidarSweep]:
    """The scene's non-empty lidar sweeps of the given dataset frames, in frame order."""
    return [s for s in scene.lidar if s.frame_index in frames and s.num_rays > 0]


@dataclass
class SweepRender:
    """A whole sweep rendered and decoded (R rays, numpy, world frame)."""

    range: np.ndarray  # [R] unnormalised expected range (the one the depth loss trains), metres
    range_normalised: np.ndarray  # [R] expected range / alpha (0 where nothing is hit)
    median_range: np.ndarray  # [R]
    intensity: np.ndarray  # [R]
    ray_drop_prob: np.ndarray  # [R]
    alpha: np.ndarray  # [R]
    points: np.ndarray  # [M, 3] o + d * range of the rays predicted as returned
    rays: LidarRayBatch  # the ground truth of the rendered rays (on the CPU)


class LidarSupervisor:
    """Draws training ray batches and computes the lidar losses of a scene model."""

    def __init__(self, sweeps: list[LidarSweep], config: LidarConfig, seed: int = 0) -> None:
        if not sweeps:
            raise ValueError("LidarSupervisor needs at least one non-empty training sweep")
        self.sweeps = sweeps
        self.config = config
        self.generator = torch.Generator().manual_seed(seed)

    def is_lidar_step(self, step: int) -> bool:
        return step % max(1, self.config.every_n_steps) == 0

    def sample(self, device: torch.device | str) -> tuple[LidarRayBatch, Tensor]:
        """A ray batch of one random training sweep and that sweep's sensor pose [4, 4]."""
        k = int(torch.randint(len(self.sweeps), (1,), generator=self.generator))
        sweep = self.sweeps[k]
        rays = sample_rays(sweep, self.config.rays_per_step, self.generator, device)
        return rays, torch.as_tensor(sweep.sensor_to_world, dtype=torch.float32, device=device)

    def render_batch(self, scene_model, rays: LidarRayBatch, sensor_to_world: Tensor) -> dict[str, Tensor]:
        """Differentiable lidar outputs of a batch: ``lidar_range`` (unnormalised), ``lidar_alpha``,
        ``lidar_intensity``, ``lidar_ray_drop_logit``, ``lidar_ray_drop_prob`` [R] and, when the
        line-of-sight loss is on, ``lidar_alpha_before_cutoff`` [R]; plus the render objects."""
        cfg = self.config
        cutoff = None
        if cfg.losses.line_of_sight > 0:
            # Dropped rays have no measured range: a cut-off of 0 counts nothing in front of them.
            cutoff = torch.where(rays.returned, rays.ranges - cfg.losses.line_of_sight_margin, 0.0)
        render, head = scene_model.render_lidar(rays, sensor_to_world, cfg.num_time_bins, cutoff_ranges=cutoff,
                                                **cfg.rasterizer_kwargs())  # fmt: skip
        out = {
            "lidar_range": render.range_unnormalised[:, 0],
            "lidar_alpha": render.alpha[:, 0],
            "lidar_intensity": head.intensity,
            "lidar_ray_drop_logit": head.ray_drop_logit,
            "lidar_ray_drop_prob": head.ray_drop_prob,
            "lidar_render": render,
            "lidar_head_output": head,
            "lidar_rays": rays,
        }
        if render.alpha_before_cutoff is not None:
            out["lidar_alpha_before_cutoff"] = render.alpha_before_cutoff[:, 0]
        return out

    def losses(self, outputs: dict) -> dict[str, Tensor]:
        """The weighted lidar losses of the outputs of :meth:`render_batch`."""
        return lidar_losses(outputs["lidar_render"], outputs["lidar_head_output"], outputs["lidar_rays"],
                            self.config.losses)  # fmt: skip


@torch.no_grad()
def render_sweep(
    scene_model,
    sweep: LidarSweep,
    config: LidarConfig,
    device: torch.device | str = "cpu",
    seed: int = 0,
) -> SweepRender:
    """Render every ray of ``sweep`` (or ``config.eval_max_rays_per_sweep`` of them, drawn with
    ``seed``) and decode range, intensity, ray drop and the predicted point cloud."""
    n = config.eval_max_rays_per_sweep or sweep.num_rays
    rays = sample_rays(sweep, n, torch.Generator().manual_seed(seed), device)
    sensor_to_world = torch.as_tensor(sweep.sensor_to_world, dtype=torch.float32, device=device)
    render, head = scene_model.render_lidar(rays, sensor_to_world, config.num_time_bins, **config.rasterizer_kwargs())
    rng = render.range_unnormalised[:, 0]
    drop = head.ray_drop_prob
    keep = drop < config.drop_threshold
    points = rays.origins[keep] + rays.directions[keep] * rng[keep, None]
    cpu = rays.to("cpu")
    return SweepRender(
        range=rng.cpu().numpy(), range_normalised=render.range[:, 0].cpu().numpy(),
        median_range=render.median_range[:, 0].cpu().numpy(), intensity=head.intensity.cpu().numpy(),
        ray_drop_prob=drop.cpu().numpy(), alpha=render.alpha[:, 0].cpu().numpy(), points=points.cpu().numpy(), rays=cpu,
    )  # fmt: skip
