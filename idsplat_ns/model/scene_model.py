"""The IDSplat scene model without nerfstudio: Gaussians (static + per-instance), instance
trajectories, appearance decoder and sensor embeddings, rendered for a camera at a time.

Static Gaussians (instance ID 0) live in the world frame; Gaussians of instance k live in k's
canonical frame and are moved by k's trajectory pose at the render time; an instance whose
trajectory does not span the render time is absent (its Gaussians are not rendered).

Optional parts: the lidar head (2-layer MLP decoding composited features into intensity and
ray-drop logit; only for scenes with lidar) and per-camera learnable time offsets (seconds, added
to each camera's render time; only when there are instances whose poses depend on the time).
Sensor embeddings and time offsets exist only for the cameras that have training images
(``embedded_sensors``); another camera renders with a zero embedding and no offset, which is what
a zero-initialised row that never receives a gradient would give.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import torch
from torch import Tensor, nn

from idsplat_ns.model.decoders import RGBDecoderCNN
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.lidar_head import LidarHead, LidarHeadOutput
from idsplat_ns.model.lidar_render import LidarRayBatch, render_lidar_rays
from idsplat_ns.render import LidarRender, rasterize_camera


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
                 trajectories: Optional[nn.Module] = None, background=(0.5, 0.5, 0.5), *,
                 lidar_head_hidden: Optional[int] = None, camera_time_offsets: bool = False,
                 embedded_sensors: Optional[Sequence[int]] = None) -> None:
        """``lidar_head_hidden``: hidden width of the lidar head (None: no lidar head, camera-only
        scene). ``camera_time_offsets``: learn a time offset per camera (only with trajectories).
        ``embedded_sensors``: the sensor indices (of ``num_sensors``) that get an embedding and a
        time offset, in row order (None: all)."""
        super().__init__()
        self.gaussians = gaussians
        self.trajectories = trajectories
        embedded = list(range(num_sensors)) if embedded_sensors is None else sorted(set(int(s) for s in embedded_sensors))
        if any(not 0 <= s < num_sensors for s in embedded):
            raise ValueError(f"SceneModel: embedded_sensors {embedded} outside 0..{num_sensors - 1}")
        # Sensor index -> row of the embedding / offset tables (-1: none). Not in the state dict:
        # the model is rebuilt from the same data and split before a checkpoint is loaded.
        self.sensor_rows = [embedded.index(s) if s in embedded else -1 for s in range(num_sensors)]
        self.sensor_embedding = nn.Embedding(len(embedded), decoder.sensor_embedding_dim)
        nn.init.zeros_(self.sensor_embedding.weight)
        self.rgb_decoder = RGBDecoderCNN(decoder.feature_dim, decoder.sensor_embedding_dim, decoder.hidden, decoder.kernel, decoder.blocks)
        self.background = nn.Parameter(torch.logit(torch.tensor(background, dtype=torch.float32).clamp(0.01, 0.99)))
        self.lidar_head = None if lidar_head_hidden is None else LidarHead(decoder.feature_dim, lidar_head_hidden)
        # A time offset only moves instances: without trajectories it would get no gradient.
        self.camera_time_offset = (
            nn.Parameter(torch.zeros(len(embedded))) if camera_time_offsets and trajectories is not None else None
        )

    @property
    def has_instances(self) -> bool:
        return self.trajectories is not None

    def camera_time(self, time: Optional[float], sensor: int) -> Optional[float | Tensor]:
        """The render time of camera ``sensor``: ``time`` plus its learnable offset (a float64
        scalar tensor that carries the offset's gradient) when offsets are learnt."""
        row = self.sensor_rows[sensor] if 0 <= sensor < len(self.sensor_rows) else -1
        if time is None or self.camera_time_offset is None or row < 0:
            return time
        return torch.tensor(time, dtype=torch.float64, device=self.camera_time_offset.device) + \
            self.camera_time_offset[row].double()

    def sensor_embedding_of(self, sensor: int) -> Tensor:  # -> [1, E]
        """The embedding of camera ``sensor``; zeros for a camera without one (no training image)."""
        row = self.sensor_rows[sensor] if 0 <= sensor < len(self.sensor_rows) else -1
        weight = self.sensor_embedding.weight
        return weight[row : row + 1] if row >= 0 else weight.new_zeros(1, weight.shape[1])

    def posed_gaussians(self, time: Optional[float | Tensor]) -> dict[str, Tensor]:
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
        g = self.posed_gaussians(self.camera_time(time, sensor))
        feats = torch.cat([g["colors"], g["features"]], dim=1)
        out = rasterize_camera(
            g["means"], g["quats"], g["scales"], g["opacities"], feats, viewmat[None], K[None], width, height,
            # per-instance maps cost a compositing channel each: only when instances exist
            instance_ids=g["instance_ids"] if self.has_instances else None,
        )
        alpha = out.alpha[0]
        background = torch.sigmoid(self.background)
        base = out.features[0, ..., :3] + (1 - alpha) * background
        emb = self.sensor_embedding_of(sensor)
        rgb = self.rgb_decoder(base[None], out.features[:, ..., 3:], emb)[0]
        return {
            "rgb": rgb,
            "depth": out.depth[0],
            "accumulation": alpha,
            "instance_id": out.instance_id[0, ..., None].float(),
            "background": background,
        }

    def render_lidar(
        self,
        rays: LidarRayBatch,
        sensor_to_world: Tensor,  # [4, 4] the sweep's sensor pose
        num_time_bins: int = 4,
        cutoff_ranges: Optional[Tensor] = None,  # [R] line-of-sight cut-off from each ray's origin
        **rasterizer_kwargs,
    ) -> tuple[LidarRender, LidarHeadOutput]:
        """Render lidar rays at their own times (time bins, instances posed per bin) and decode
        intensity and ray drop with the lidar head (see :func:`render_lidar_rays`)."""
        if self.lidar_head is None:
            raise RuntimeError("SceneModel.render_lidar: this model has no lidar head (a camera-only scene)")
        render = render_lidar_rays(self.posed_gaussians, rays, sensor_to_world, num_time_bins,
                                   cutoff_ranges=cutoff_ranges, **rasterizer_kwargs)  # fmt: skip
        return render, self.lidar_head(render.features)
