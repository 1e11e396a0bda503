"""Lidar decoder: rendered per-ray feature vector -> intensity and ray-drop logit.

Per the paper's supplementary (following SplatAD): a small MLP of 2 layers with a hidden dimension
of 32 decodes the composited Gaussian feature vector (13-d) of a lidar ray into the ray's intensity
and its ray-drop probability.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass
class LidarHeadOutput:
    """Decoded per-ray lidar properties (R rays)."""

    intensity: Tensor  # [R] in (0, 1)
    ray_drop_logit: Tensor  # [R] logit of P(no return)

    @property
    def ray_drop_prob(self) -> Tensor:  # [R]
        """Probability that the ray returned nothing."""
        return torch.sigmoid(self.ray_drop_logit)


class LidarHead(nn.Module):
    """Linear(D, 32) -> ReLU -> Linear(32, 2); output 0 is intensity (sigmoid), 1 the drop logit."""

    def __init__(self, feature_dim: int = 13, hidden: int = 32) -> None:
        super().__init__()
        self.feature_dim = feature_dim
        self.mlp = nn.Sequential(
            nn.Linear(feature_dim, hidden), nn.ReLU(), nn.Linear(hidden, 2)
        )

    def forward(
        self, features: Tensor
    ) -> LidarHeadOutput:  # features: [R, D] composited per ray
        out = self.mlp(features)
        return LidarHeadOutput(
            intensity=torch.sigmoid(out[:, 0]), ray_drop_logit=out[:, 1]
        )
