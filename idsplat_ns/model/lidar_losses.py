"""Lidar reconstruction losses of the paper (Sec. 3.5; loss form and weights from SplatAD).

``L_lidar = 0.1 L_depth + 0.1 L_los + 1.0 L_inten + 0.1 L_BCE`` with, over one batch of rays:

* ``L_depth``: mean over returned rays of ``(rendered range - measured range)^2`` (m^2), where the
  rendered range is the **unnormalised** expected range ``sum_i w_i r_i`` (= alpha x the
  alpha-normalised expected range), as SplatAD renders it.
* ``L_los`` (line of sight): mean over returned rays of the summed opacities ``sum_i alpha_i`` of
  the Gaussians the ray meets before its measured range minus a margin of 0.8 m (SplatAD's
  ``alpha_sum_until_points`` with ``line_of_sight_dist`` 0.8): free space must stay empty.
* ``L_inten``: mean over returned rays of ``(decoded intensity - measured intensity)^2``.
* ``L_BCE``: mean over all rays of the binary cross-entropy between the decoded ray-drop logit
  and the target 1 for rays that returned nothing, 0 for returned rays.

As in SplatAD, the returned rays whose squared depth error is at or above the batch's 95th
percentile are left out of the depth, line-of-sight and intensity means (a few rays on depth
discontinuities, or not yet covered by any Gaussian, would otherwise dominate the batch).

**Returned rays that no Gaussian covers.** With the unnormalised range such a ray renders range
0, so its depth error is large and, where any Gaussian touches the ray, the gradient raises that
Gaussian's opacity and pulls it to the measured range; dividing by a small alpha (the normalised
range) would instead make the range of a barely covered ray jump to whatever faint Gaussian is
there, with gradients of size 1/alpha. A ray that no Gaussian touches at all gives no gradient
(its loss is constant); the random initial points and MCMC relocation are what fill such holes,
and the 95% quantile keeps those rays from drowning the rest of the batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from idsplat_ns.model.lidar_head import LidarHeadOutput
from idsplat_ns.model.lidar_render import LidarRayBatch
from idsplat_ns.render import LidarRender
from idsplat_ns.ranges import FRACTION, bounded


@dataclass
class LidarLossConfig:
    """Weights and settings of the lidar loss terms (paper = SplatAD defaults)."""

    depth: float = 0.1
    """Weight of the L2 loss on the unnormalised expected range of returned rays (metres squared)."""
    line_of_sight: float = 0.1
    """Weight of the line-of-sight loss (summed opacity before the measured range minus the margin)."""
    intensity: float = 1.0
    """Weight of the L2 loss on the decoded intensity of returned rays."""
    ray_drop: float = 0.1
    """Weight of the binary cross-entropy on the ray-drop logit over all rays."""
    line_of_sight_margin: float = 0.8
    """Metres before the measured range where the line-of-sight loss stops counting (SplatAD: 0.8)."""
    depth_quantile: float = bounded(0.95, FRACTION)
    """Returned rays with a squared depth error at or above this quantile of the batch are left out
    of the depth, line-of-sight and intensity terms (SplatAD: 0.95; 1.0 keeps every ray)."""


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:  # values, mask: [R]
    """Mean of ``values`` where ``mask``; 0 (still in the graph) when the mask is empty."""
    m = mask.to(values.dtype)
    return (values * m).sum() / m.sum().clamp_min(1.0)


def lidar_losses(
    render: LidarRender,
    head_out: LidarHeadOutput,
    rays: LidarRayBatch,
    config: LidarLossConfig | None = None,
) -> dict[str, torch.Tensor]:
    """Weighted lidar losses: ``lidar_depth``, ``lidar_intensity``, ``lidar_ray_drop`` and, when
    ``render.alpha_before_cutoff`` is present (the rays were rendered with a cut-off at their
    measured range minus ``config.line_of_sight_margin``), ``lidar_line_of_sight`` (scalars).

    ``render`` and ``head_out`` are for the rays of ``rays`` in the same order (see
    :func:`~idsplat_ns.model.lidar_render.render_lidar_rays` and
    :class:`~idsplat_ns.model.lidar_head.LidarHead`).
    """
    cfg = config if config is not None else LidarLossConfig()
    returned = rays.returned
    sq_err = (render.range_unnormalised[:, 0] - rays.ranges) ** 2
    kept = returned
    if cfg.depth_quantile < 1.0:
        # The quantile of the returned rays' errors with no read of the device: the others are NaN
        # (all NaN without a returned ray, and then no ray is kept either way).
        err = sq_err.detach()
        threshold = torch.nanquantile(torch.where(returned, err, torch.full_like(err, float("nan"))), cfg.depth_quantile)
        # "< threshold" as SplatAD, but never drop every ray (all errors equal, e.g. all zero).
        below = err < threshold
        kept = returned & torch.where((returned & below).any(), below, torch.ones_like(below))
    depth = _masked_mean(sq_err, kept)
    intensity = _masked_mean((head_out.intensity - rays.intensities) ** 2, kept)
    drop = F.binary_cross_entropy_with_logits(head_out.ray_drop_logit, (~returned).to(head_out.ray_drop_logit.dtype))
    out = {
        "lidar_depth": cfg.depth * depth,
        "lidar_intensity": cfg.intensity * intensity,
        "lidar_ray_drop": cfg.ray_drop * drop,
    }
    if render.alpha_before_cutoff is not None:
        out["lidar_line_of_sight"] = cfg.line_of_sight * _masked_mean(render.alpha_before_cutoff[:, 0], kept)
    return out
