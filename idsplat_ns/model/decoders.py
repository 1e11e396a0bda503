"""Appearance decoders of the camera path: sensor embeddings and the small residual CNN.

Per the paper's supplementary: each Gaussian carries a base colour (3) and a feature vector (13);
rendered feature images are concatenated with the camera's sensor embedding (8) and decoded by a
CNN of two residual blocks (32 channels, kernel 3) with a linear output layer into a colour
correction that is added to the base colour in logit space.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class ResidualBlock(nn.Module):
    """conv3x3 -> ReLU -> conv3x3, plus the input."""

    def __init__(self, channels: int, kernel_size: int = 3) -> None:
        super().__init__()
        pad = kernel_size // 2
        self.conv1 = nn.Conv2d(channels, channels, kernel_size, padding=pad)
        self.conv2 = nn.Conv2d(channels, channels, kernel_size, padding=pad)

    def forward(self, x: Tensor) -> Tensor:  # x: [B, C, H, W]
        return x + self.conv2(torch.relu(self.conv1(torch.relu(x))))


class RGBDecoderCNN(nn.Module):
    """Decode rendered features (+ sensor embedding) to RGB."""

    def __init__(self, feature_dim: int = 13, embedding_dim: int = 8, hidden: int = 32, kernel_size: int = 3, num_blocks: int = 2) -> None:
        super().__init__()
        self.inp = nn.Conv2d(feature_dim + embedding_dim, hidden, 1)
        self.blocks = nn.Sequential(*[ResidualBlock(hidden, kernel_size) for _ in range(num_blocks)])
        self.out = nn.Conv2d(hidden, 3, 1)  # the linear output layer
        # Start as the identity on the base colour so early training is driven by the Gaussians.
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(
        self,
        base_rgb: Tensor,  # [B, H, W, 3] composited base colour incl. background, in [0, 1]
        features: Tensor,  # [B, H, W, F] composited feature vectors
        embedding: Tensor,  # [B, E] sensor embedding of each image
    ) -> Tensor:  # [B, H, W, 3] in (0, 1)
        b, h, w, _ = features.shape
        emb = embedding[:, :, None, None].expand(b, embedding.shape[1], h, w)
        x = torch.cat([features.permute(0, 3, 1, 2), emb], 1)
        delta = self.out(self.blocks(self.inp(x))).permute(0, 2, 3, 1)
        logit = torch.logit(base_rgb.clamp(1e-4, 1 - 1e-4))
        return torch.sigmoid(logit + delta)
