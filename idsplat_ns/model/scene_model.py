"""The IDSplat scene model without nerfstudio: Gaussians (static + per-instance), instance
trajectories, appearance decoder and sensor embeddings, rendered for a camera at a time.

Static Gaussians (instance ID 0) live in the world frame; Gaussians of instance k live in k's
canonical frame and are moved by k's trajectory pose at the render time; an instance whose
trajectory does not span the render time is absent (its Gaussians are not rendered).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor, nn

from idsplat_ns.model.decoders import RGBDecoderCNN
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.render import rasterize_camera


@dataclass
class DecoderConfig:
    """Sizes of the appearance path (paper: 13-d features, 8-d sensor embeddings, CNN 32/3/2)."""

    feature_dim: int = 13
    """Per-Gaussian feature vector size."""
    sensor_embedding_dim: int = 8
    """Per-camera appearance embedding size."""
    hidden: int = 32
    """Channels of the RGB decoder CNN."""
    kernel: int = 3
    """Kernel size of the RGB decoder CNN."""
    blocks: int = 2
    """Residual blocks of the RGB decoder CNN."""


class SceneModel(nn.Module):
    """Everything that is optimised, and the camera rendering of it at a time."""

    def __init__(self, gaussians: GaussianSet, num_sensors: int, decoder: DecoderConfig,
                 trajectories: Optional[nn.Module] = None, background=(0.5, 0.5, 0.5)) -> None:
        super().__init__()
        self.gaussians = gaussians
        self.trajectories = trajectories
        self.sensor_embedding = nn.Embedding(num_sensors, decoder.sensor_embedding_dim)
        nn.init.zeros_(self.sensor_embedding.weight)
        self.rgb_decoder = RGBDecoderCNN(decoder.feature_dim, decoder.sensor_embedding_dim, decoder.hidden, decoder.kernel, decoder.blocks)
        self.background = nn.Parameter(torch.logit(torch.tensor(background, dtype=torch.float32).clamp(0.01, 0.99)))

    @property
    def has_instances(self) -> bool:
        return self.trajectories is not None

    def posed_gaussians(self, time: Optional[float]) -> dict[str, Tensor]:
        """Activated Gaussians in the world at ``time`` (seconds); absent instances removed."""
        g = self.gaussians.activated()
        ids = self.gaussians.instance_ids
        if self.trajectories is None:  # a static scene: nothing to pose or drop
            return g | {"instance_ids": ids}
        if time is None:  # without a time only the static background is defined
            keep = ids == 0
            return {k: v[keep] for k, v in g.items()} | {"instance_ids": ids[keep]}
        from idsplat_ns.model.composition import compose_gaussians

        R, t, present = self.trajectories.poses_at(time)
        means, quats, keep = compose_gaussians(g["means"], g["quats"], ids, R, t, present, self.trajectories.instance_ids)
        out = {k: v[keep] for k, v in g.items() if k not in ("means", "quats")}
        return out | {"means": means, "quats": quats, "instance_ids": ids[keep]}

    def render_camera(
        self,
        viewmat: Tensor,  # [4, 4] world-to-camera, OpenCV axes
        K: Tensor,  # [3, 3]
        width: int,
        height: int,
        time: Optional[float],
        sensor: int = 0,
    ) -> dict[str, Tensor]:
        """rgb [H, W, 3], depth / accumulation [H, W, 1], instance_id [H, W, 1] (-1 empty, 0 static)."""
        g = self.posed_gaussians(time)
        feats = torch.cat([g["colors"], g["features"]], dim=1)
        out = rasterize_camera(
            g["means"], g["quats"], g["scales"], g["opacities"], feats, viewmat[None], K[None], width, height,
            # per-instance maps cost a compositing channel each: only when instances exist
            instance_ids=g["instance_ids"] if self.has_instances else None,
        )
        alpha = out.alpha[0]
        background = torch.sigmoid(self.background)
        base = out.features[0, ..., :3] + (1 - alpha) * background
        emb = self.sensor_embedding.weight[sensor : sensor + 1]
        rgb = self.rgb_decoder(base[None], out.features[:, ..., 3:], emb)[0]
        return {
            "rgb": rgb,
            "depth": out.depth[0],
            "accumulation": alpha,
            "instance_id": out.instance_id[0, ..., None].float(),
            "background": background,
        }
