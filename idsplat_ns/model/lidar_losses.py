"""Lidar reconstruction losses of the paper (Sec. 3.5, weights from SplatAD).

``L_lidar = 0.1 L_depth + 0.1 L_los + 1.0 L_inten + 0.1 L_BCE``, of which this module computes:

* ``L_depth``: mean over returned rays of ``(rendered expected range - measured range)^2`` (m^2).
* ``L_inten``: mean over returned rays of ``(decoded intensity - measured intensity)^2``.
* ``L_BCE``: mean over all rays of the binary cross-entropy between the decoded ray-drop logit
  and the target 1 for rays that returned nothing, 0 for returned rays.

**Not computed: the line-of-sight loss** (paper weight 0.1), which penalises the opacity
accumulated *before each ray's own measured range*. That needs a per-ray truncation of the
compositing, which :func:`~idsplat_ns.render.rasterize_lidar` does not offer: per-Gaussian
features cannot depend on the ray, so a composited channel can only truncate at one range per
render call. (Range buckets - one indicator channel per threshold - would give a lower bound
with a margin that varies per ray, not the loss itself, so it is not substituted here.) When the
rasterizer gains a per-ray truncation range, add the term with weight 0.1.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from idsplat_ns.model.lidar_head import LidarHeadOutput
from idsplat_ns.model.lidar_render import LidarRayBatch
from idsplat_ns.render import LidarRender


@dataclass
class LidarLossWeights:
    """Weights of the lidar loss terms (paper / SplatAD defaults)."""

    depth: float = 0.1
    """Weight of the L2 loss on the expected range of returned rays (metres squared)."""
    intensity: float = 1.0
    """Weight of the L2 loss on the decoded intensity of returned rays."""
    ray_drop: float = 0.1
    """Weight of the binary cross-entropy on the ray-drop logit over all rays."""


def _masked_mean(
    values: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:  # values, mask: [R]
    """Mean of ``values`` where ``mask``; 0 (still in the graph) when the mask is empty."""
    m = mask.to(values.dtype)
    return (values * m).sum() / m.sum().clamp_min(1.0)


def lidar_losses(
    render: LidarRender,
    head_out: LidarHeadOutput,
    rays: LidarRayBatch,
    weights: LidarLossWeights | None = None,
) -> dict[str, torch.Tensor]:
    """Weighted lidar losses (default weights when ``weights`` is None): ``lidar_depth``, ``lidar_intensity``, ``lidar_ray_drop`` (scalars).

    ``render`` and ``head_out`` are for the rays of ``rays`` in the same order (see
    :func:`~idsplat_ns.model.lidar_render.render_lidar_rays` and
    :class:`~idsplat_ns.model.lidar_head.LidarHead`). The line-of-sight term is not included (see
    the module docstring).
    """
    weights = weights if weights is not None else LidarLossWeights()
    returned = rays.returned
    depth = _masked_mean((render.range[:, 0] - rays.ranges) ** 2, returned)
    intensity = _masked_mean((head_out.intensity - rays.intensities) ** 2, returned)
    drop = F.binary_cross_entropy_with_logits(
        head_out.ray_drop_logit, (~returned).to(head_out.ray_drop_logit.dtype)
    )
    return {
        "lidar_depth": weights.depth * depth,
        "lidar_intensity": weights.intensity * intensity,
        "lidar_ray_drop": weights.ray_drop * drop,
    }
