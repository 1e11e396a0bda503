"""Appearance decoders of the camera path: sensor embeddings and the small residual CNN.

Per the paper's supplementary: each Gaussian carries a base colour (3) and a feature vector (13);
rendered feature images are concatenated with the camera's sensor embedding (8) and decoded by a
CNN of two residual blocks (32 channels, kernel 3) with a linear output layer into a colour
correction that is added to the base colour in logit space.

View-dependent colour (optional, ``view_dim=3``): the per-pixel unit ray direction in the world
frame is three more input channels, as in SplatAD (raw directions, no encoding). World frame,
not camera frame: in the camera frame a pixel's direction is the same in every image. It would
say where in the image a pixel is, not from where the surface is seen.
"""

from __future__ import annotations

from typing import Optional

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

    def __init__(self, feature_dim: int = 13, embedding_dim: int = 8, hidden: int = 32, kernel_size: int = 3,
                 num_blocks: int = 2, view_dim: int = 0) -> None:
        """``view_dim``: channels of the view-direction input (3 for world-frame ray directions, 0 for none)."""
        super().__init__()
        self.view_dim = view_dim
        self.inp = nn.Conv2d(feature_dim + embedding_dim + view_dim, hidden, 1)
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
        view_dirs: Optional[Tensor] = None,  # [B, H, W, view_dim] ray directions (when view_dim > 0)
    ) -> Tensor:  # [B, H, W, 3] in (0, 1)
        b, h, w, _ = features.shape
        emb = embedding[:, :, None, None].expand(b, embedding.shape[1], h, w)
        parts = [features.permute(0, 3, 1, 2), emb]
        if self.view_dim:
            if view_dirs is None or view_dirs.shape[-1] != self.view_dim:
                raise ValueError(f"RGBDecoderCNN: needs view_dirs [B, H, W, {self.view_dim}]")
            parts.append(view_dirs.permute(0, 3, 1, 2))
        x = torch.cat(parts, 1)
        delta = self.out(self.blocks(self.inp(x))).permute(0, 2, 3, 1)
        logit = torch.logit(base_rgb.clamp(1e-4, 1 - 1e-4))
        return torch.sigmoid(logit + delta)
