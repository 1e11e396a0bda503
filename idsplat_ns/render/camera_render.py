"""What the camera rasterizers return (both backends): :class:`CameraRender`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from torch import Tensor


@dataclass
class CameraRender:
    """Per-pixel outputs of :func:`rasterize_camera` (no background composited)."""

    features: Tensor  # [C, H, W, D] sum_i w_i f_i
    alpha: Tensor  # [C, H, W, 1] sum_i w_i
    depth: Tensor  # [C, H, W, 1] expected depth sum_i w_i d_i / alpha, 0 where alpha == 0
    median_depth: Tensor  # [C, H, W, 1] depth where transmittance crosses 0.5 (see reference.py)
    instance_id: Tensor  # [C, H, W] int64 instance of largest weight, -1 where alpha == 0
    means2d: Tensor  # [C, N, 2] projected means (call .retain_grad() for densification stats)
    radii: Tensor  # [C, N] int32 pixel radii, 0 = culled
    depths: Tensor  # [C, N] camera-space depth of every Gaussian
    instance_alpha: Optional[Tensor] = None  # [C, H, W, K] per-instance alpha (if requested)
    instance_values: Optional[Tensor] = None  # [K] instance ID of each instance_alpha channel
