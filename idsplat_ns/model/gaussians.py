"""The Gaussian parameter set (raw, unactivated) and its activations.

Storage follows 3DGS practice: log scales, logit opacities, unnormalised quaternions, base colour
as logits; ``instance_ids`` is a buffer (0 = static, in the world frame).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from idsplat_ns.model.initialisation import InitialPoints


class GaussianSet(nn.Module):
    """N Gaussians with base colour and a feature vector each."""

    PARAM_NAMES = ("means", "scales", "quats", "opacities", "features_rgb", "features")

    def __init__(self, num: int, feature_dim: int = 13) -> None:
        super().__init__()
        self.means = nn.Parameter(torch.zeros(num, 3))
        self.scales = nn.Parameter(torch.zeros(num, 3))
        self.quats = nn.Parameter(torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(num, 1))
        self.opacities = nn.Parameter(torch.zeros(num))
        self.features_rgb = nn.Parameter(torch.zeros(num, 3))
        self.features = nn.Parameter(torch.zeros(num, feature_dim))
        self.register_buffer("instance_ids", torch.zeros(num, dtype=torch.int64))

    @classmethod
    def from_points(cls, init: InitialPoints, feature_dim: int = 13, opacity: float = 0.5, seed: int = 0) -> "GaussianSet":
        g = cls(len(init.means), feature_dim)
        gen = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            g.means.copy_(torch.from_numpy(init.means).float())
            g.scales.copy_(torch.from_numpy(np.log(init.scales)).float()[:, None].expand(-1, 3))
            q = torch.randn(len(init.means), 4, generator=gen)  # random orientations (isotropic anyway)
            g.quats.copy_(q / q.norm(dim=1, keepdim=True))
            g.opacities.fill_(math.log(opacity / (1 - opacity)))
            g.features_rgb.copy_(torch.logit(torch.from_numpy(init.colors).float().clamp(0.02, 0.98)))
            g.features.normal_(0.0, 0.01, generator=gen)
        return g

    @property
    def num(self) -> int:
        return self.means.shape[0]

    def activated(self) -> dict[str, Tensor]:
        """Activated tensors for the rasterizer: scales (metres), opacities in (0, 1), colours."""
        return {
            "means": self.means,
            "quats": self.quats,
            "scales": torch.exp(self.scales),
            "opacities": torch.sigmoid(self.opacities),
            "colors": torch.sigmoid(self.features_rgb),
            "features": self.features,
        }

    def resize_(self, num: int) -> None:
        """Reallocate every tensor for ``num`` Gaussians (before loading a checkpoint of that size)."""
        for name in self.PARAM_NAMES:
            old = getattr(self, name)
            setattr(self, name, nn.Parameter(old.new_zeros((num,) + tuple(old.shape[1:]))))
        self.instance_ids = self.instance_ids.new_zeros(num)
