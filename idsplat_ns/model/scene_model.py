"""The IDSplat scene model without nerfstudio: Gaussians (static + per-instance), instance
trajectories, appearance decoder and sensor embeddings, rendered for a camera at a time.

Static Gaussians (instance ID 0) live in the world frame; Gaussians of instance k live in k's
canonical frame and are moved by k's trajectory pose at the render time; an instance whose
trajectory does not span the render time is absent (its Gaussians are not rendered).

Optional parts: a deformation of non-rigid instances (pedestrians, cyclists; model/deformation.py),
the lidar head (2-layer MLP decoding composited features into intensity and
ray-drop logit; only for scenes with lidar) and per-camera learnable time offsets (seconds, added
to each camera's render time; only when there are instances whose poses depend on the time).
Sensor embeddings and time offsets exist only for the cameras that have training images
(``embedded_sensors``); another camera renders with a zero embedding and no offset, which is what
a zero-initialised row that never receives a gradient would give.

Sensor fidelity (docs/sensor_fidelity.md): a render of a rolling-shutter image draws each
Gaussian where it is when its line is exposed. The camera moves, and instance Gaussians move
with their trajectory's velocity. With ``view_directions`` the RGB decoder also gets each
pixel's world-frame ray direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import torch
from torch import Tensor, nn

from idsplat_ns.model.camera_shutter import ImageShutter
from idsplat_ns.model.composition import compose_gaussians, compose_gaussians_at_times, gaussian_velocities
from idsplat_ns.model.decoders import RGBDecoderCNN
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.lidar_head import LidarHead, LidarHeadOutput
from idsplat_ns.model.lidar_render import LidarRayBatch, PosedBins, render_lidar_rays_binned
from idsplat_ns.render import LidarRender, rasterize_camera
from idsplat_ns.render.camera import CAMERA_BACKENDS
from idsplat_ns.ranges import AT_LEAST_ONE, bounded


@dataclass
class DecoderConfig:
    """Sizes of the appearance path (paper: 13-d features, 8-d sensor embeddings, CNN 32/3/2)."""

    feature_dim: int = bounded(13, AT_LEAST_ONE)
    """Per-Gaussian feature vector size."""
    sensor_embedding_dim: int = 8
    """Per-camera appearance embedding size."""
    hidden: int = bounded(32, AT_LEAST_ONE)
    """Channels of the RGB decoder CNN."""
    kernel: int = bounded(3, AT_LEAST_ONE)
    """Kernel size of the RGB decoder CNN."""
    blocks: int = bounded(2, AT_LEAST_ONE)
    """Residual blocks of the RGB decoder CNN."""


class SceneModel(nn.Module):
    """Everything that is optimised, and the camera rendering of it at a time."""

    def __init__(self, gaussians: GaussianSet, num_sensors: int, decoder: DecoderConfig,
                 trajectories: Optional[nn.Module] = None, background=(0.5, 0.5, 0.5), *,
                 lidar_head_hidden: Optional[int] = None, camera_time_offsets: bool = False,
                 embedded_sensors: Optional[Sequence[int]] = None, view_directions: bool = False,
                 deformation: Optional[nn.Module] = None, camera_backend: str = "auto") -> None:
        """``lidar_head_hidden``: hidden width of the lidar head (None: no lidar head, camera-only
        scene). ``camera_time_offsets``: learn a time offset per camera (only with trajectories).
        ``embedded_sensors``: the sensor indices (of ``num_sensors``) that get an embedding and a
        time offset, in row order (None: all). ``view_directions``: the RGB decoder also takes
        each pixel's world-frame ray direction (view-dependent colour). ``deformation``: an
        :class:`~idsplat_ns.model.deformation.InstanceDeformation` for non-rigid instances (None:
        every instance rigid). ``camera_backend``: ``rasterize_camera``'s (auto, gsplat or torch)."""
        super().__init__()
        if camera_backend not in CAMERA_BACKENDS:
            raise ValueError(f"SceneModel: camera_backend {camera_backend!r}; use 'auto', 'gsplat' or 'torch'")
        self.camera_backend = camera_backend
        # The tile rasterizer's compositor (``rasterize_camera``'s ``compositor``); benches switch it.
        self.camera_compositor = "auto"
        self.decoder_config = decoder
        self.gaussians = gaussians
        self.trajectories = trajectories
        self.deformation = deformation
        embedded = list(range(num_sensors)) if embedded_sensors is None else sorted(set(int(s) for s in embedded_sensors))
        if any(not 0 <= s < num_sensors for s in embedded):
            raise ValueError(f"SceneModel: embedded_sensors {embedded} outside 0..{num_sensors - 1}")
        # Sensor index -> row of the embedding / offset tables (-1: none). Not in the state dict:
        # the model is rebuilt from the same data and split before a checkpoint is loaded.
        self.sensor_rows = [embedded.index(s) if s in embedded else -1 for s in range(num_sensors)]
        self.sensor_embedding = nn.Embedding(len(embedded), decoder.sensor_embedding_dim)
        nn.init.zeros_(self.sensor_embedding.weight)
        self.set_view_directions(view_directions)
        self.background = nn.Parameter(torch.logit(torch.tensor(background, dtype=torch.float32).clamp(0.01, 0.99)))
        self.lidar_head = None if lidar_head_hidden is None else LidarHead(decoder.feature_dim, lidar_head_hidden)
        # A time offset only moves instances: without trajectories it would get no gradient.
        self.camera_time_offset = (
            nn.Parameter(torch.zeros(len(embedded))) if camera_time_offsets and trajectories is not None else None
        )

    def set_view_directions(self, enabled: bool) -> None:
        """(Re)build the RGB decoder with or without the view-direction input (a fresh decoder: a
        checkpoint's weights are loaded into it next)."""
        d = self.decoder_config
        self.view_directions = bool(enabled)
        self.rgb_decoder = RGBDecoderCNN(d.feature_dim, d.sensor_embedding_dim, d.hidden, d.kernel, d.blocks,
                                         view_dim=3 if enabled else 0)

    def decoder_like(self, state_dict: dict, prefix: str = "") -> None:
        """Give the RGB decoder the view-direction input of a checkpoint's ``state_dict`` (keys
        under ``prefix``): models trained without view-dependent colour have three input channels
        fewer. Call before loading the state dict."""
        weight = state_dict.get(prefix + "rgb_decoder.inp.weight")
        if weight is None:
            return
        d = self.decoder_config
        with_dirs = int(weight.shape[1]) - d.feature_dim - d.sensor_embedding_dim == 3
        if with_dirs != self.view_directions:
            device = self.background.device
            self.set_view_directions(with_dirs)
            self.rgb_decoder.to(device)

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

    def posed_gaussians(
        self, time: Optional[float | Tensor], with_velocities: bool = False, drop_absent: bool = True,
    ) -> dict[str, Tensor]:
        """Activated Gaussians in the world at ``time`` (seconds); absent instances removed.
        ``with_velocities`` adds ``velocities`` [M, 3], the world-frame velocity of each mean
        (zero for the background), when instances move; a static scene has none.
        ``drop_absent=False`` keeps absent instances' Gaussians with opacity 0 instead of removing
        them (no [N]-row gathers; for renderers that drop transparent Gaussians, as the lidar's do:
        a camera render gained nothing measurable from it at 80,000 Gaussians). Several times at
        once: :meth:`posed_gaussians_at_times`."""
        g = self.gaussians.activated()
        ids = self.gaussians.instance_ids
        if self.trajectories is None:  # a static scene: nothing to pose or drop
            return g | {"instance_ids": ids}
        if time is None:  # without a time only the static background is defined
            rows = torch.nonzero(ids == 0).squeeze(1)
            return {k: v.index_select(0, rows) for k, v in g.items()} | {"instance_ids": ids.index_select(0, rows)}

        traj_ids = self.trajectories.instance_ids
        if with_velocities:
            R, t, present, linear, angular = self.trajectories.motion_at(time)
        else:
            R, t, present = self.trajectories.poses_at(time)
        canonical = g["means"]
        if self.deformation is not None:
            canonical = canonical + self.deformation.offsets(canonical, ids, time)
        means, quats, keep = compose_gaussians(canonical, g["quats"], ids, R, t, present, traj_ids, drop=drop_absent)
        everyone = bool(keep.all())
        if everyone or not drop_absent:  # every row stays: no [N, D] gathers (nor their backward)
            out = {k: v for k, v in g.items() if k not in ("means", "quats")} | {"instance_ids": ids}
            if not everyone:  # absent instances stay, transparent
                out["opacities"] = g["opacities"] * keep
        else:
            # index_select, not a boolean mask: the mask's backward is an accumulating index_put
            # (a sort of all N rows on CUDA), index_select's one index_add.
            rows = torch.nonzero(keep).squeeze(1)
            out = {k: v.index_select(0, rows) for k, v in g.items() if k not in ("means", "quats")}
            out["instance_ids"] = ids.index_select(0, rows)
        out = out | {"means": means, "quats": quats}
        if with_velocities:
            velocities = gaussian_velocities(means, out["instance_ids"], t, linear, angular, traj_ids)
            # Transparent rows of absent instances move with no velocity (their pose is a placeholder).
            out["velocities"] = velocities if drop_absent else velocities * keep[:, None]
        return out

    def posed_gaussians_at_times(self, times: Tensor) -> PosedBins:  # times: [K] float64 seconds
        """:meth:`posed_gaussians` with ``drop_absent=False`` at K times in one batch of operations
        (a lidar batch's time bins): the trajectories are interpolated and the instances moved for
        all K times together, the activations computed once."""
        g = self.gaussians.activated()
        ids = self.gaussians.instance_ids
        k, n = times.shape[0], ids.shape[0]
        opacities = g["opacities"][None].expand(k, n)
        if self.trajectories is None:  # a static scene: every time sees the same Gaussians
            return PosedBins(g["means"][None].expand(k, n, 3), g["quats"][None].expand(k, n, 4), opacities,
                             g["scales"], g["features"])
        R, t, present = self.trajectories.poses_at_times(times)
        canonical = g["means"]
        if self.deformation is not None:  # offsets at each time: [K, N, 3]
            canonical = torch.stack([canonical + self.deformation.offsets(canonical, ids, times[i]) for i in range(k)])
        means, quats, keep = compose_gaussians_at_times(canonical, g["quats"], ids, R, t, present,
                                                        self.trajectories.instance_ids)  # fmt: skip
        # Absent instances stay, transparent: the rasterizer drops opacity 0.
        return PosedBins(means, quats, opacities * keep, g["scales"], g["features"])

    def render_camera(
        self,
        viewmat: Tensor,  # [4, 4] world-to-camera, OpenCV axes
        K: Tensor,  # [3, 3]
        width: int,
        height: int,
        time: Optional[float],
        sensor: int = 0,
        shutter: Optional[ImageShutter] = None,
    ) -> dict[str, Tensor]:
        """rgb [H, W, 3], depth / accumulation [H, W, 1], instance_id [H, W, 1] (-1 empty, 0 static).
        ``shutter``: the rolling shutter of the recorded image rendered (None: global shutter)."""
        g = self.posed_gaussians(self.camera_time(time, sensor), with_velocities=shutter is not None)
        motion = None if shutter is None else shutter.motion(width, height, viewmat.device, g.get("velocities"))
        feats = torch.cat([g["colors"], g["features"]], dim=1)
        out = rasterize_camera(
            g["means"], g["quats"], g["scales"], g["opacities"], feats, viewmat[None], K[None], width, height,
            # per-instance maps cost a compositing channel each: only when instances exist
            instance_ids=g["instance_ids"] if self.has_instances else None, motion=motion,
            backend=self.camera_backend, compositor=self.camera_compositor,
        )
        alpha = out.alpha[0]
        background = torch.sigmoid(self.background)
        base = out.features[0, ..., :3] + (1 - alpha) * background
        emb = self.sensor_embedding_of(sensor)
        dirs = ray_directions(viewmat, K, width, height)[None] if self.view_directions else None
        rgb = self.rgb_decoder(base[None], out.features[:, ..., 3:], emb, dirs)[0]
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
        # All time bins posed in one batch; an absent instance is transparent in a bin rather than
        # gathered out of every per-Gaussian tensor (the rasterizer drops opacity 0).
        render = render_lidar_rays_binned(self.posed_gaussians_at_times, rays, sensor_to_world, num_time_bins,
                                          cutoff_ranges=cutoff_ranges, **rasterizer_kwargs)  # fmt: skip
        return render, self.lidar_head(render.features)


def ray_directions(viewmat: Tensor, K: Tensor, width: int, height: int) -> Tensor:  # -> [H, W, 3]
    """World-frame unit directions of the rays through the pixel centres of a pinhole camera
    (``viewmat`` [4, 4] world-to-camera, OpenCV axes; ``K`` [3, 3])."""
    dtype, device = viewmat.dtype, viewmat.device
    v, u = torch.meshgrid(torch.arange(height, dtype=dtype, device=device) + 0.5,
                          torch.arange(width, dtype=dtype, device=device) + 0.5, indexing="ij")
    d_cam = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], -1)  # [H, W, 3]
    d = d_cam @ viewmat[:3, :3]  # R^T d_cam in row form: camera to world
    return d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
