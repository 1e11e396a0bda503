"""The IDSplat nerfstudio model. For now: static Gaussians (instances arrive with issue 7).

Camera path per the paper: Gaussians carry a base colour and a 13-d feature vector; rendered
feature images plus an 8-d sensor embedding are decoded by a small residual CNN; loss
0.8 L1 + 0.2 (1 - SSIM); resolution schedule 1/4, 1/2, full.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Type

import torch
import torch.nn.functional as F
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.models.base_model import Model, ModelConfig
from nerfstudio.utils import colormaps
from rich.console import Console
from torch import Tensor, nn

from idsplat_ns.data.images import load_rgb
from idsplat_ns.eval.image_metrics import psnr, ssim
from idsplat_ns.model.decoders import RGBDecoderCNN
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.initialisation import InitConfig, initial_points_from_scene
from idsplat_ns.model.schedules import resolution_downscale
from idsplat_ns.render import rasterize_camera

CONSOLE = Console()
OPENGL_TO_OPENCV = torch.diag(torch.tensor([1.0, -1.0, -1.0]))


@dataclass
class IDSplatModelConfig(ModelConfig):
    """IDSplat model options; defaults are the paper's."""

    _target: Type = field(default_factory=lambda: IDSplatModel)
    enable_collider: bool = False
    """Ray colliders are for ray-marching models; a rasterizer renders whole cameras."""
    feature_dim: int = 13
    """Per-Gaussian feature vector size (paper: 13)."""
    sensor_embedding_dim: int = 8
    """Per-camera appearance embedding size (paper: 8)."""
    decoder_hidden: int = 32
    """Channels of the RGB decoder CNN (paper: 32)."""
    decoder_blocks: int = 2
    """Residual blocks of the RGB decoder CNN (paper: 2)."""
    decoder_kernel: int = 3
    """Kernel size of the RGB decoder CNN (paper: 3)."""
    ssim_lambda: float = 0.2
    """Weight of (1 - SSIM); L1 gets 1 - ssim_lambda (paper: lambda_r = 0.8)."""
    resolution_schedule: Tuple[int, ...] = (3000, 6000)
    """Steps at which the render resolution doubles (paper: 1/4 until 3000, 1/2 until 6000, then full)."""
    max_lidar_points: int = 5_000_000
    """Cap on lidar points used for initialisation (paper: 5M)."""
    num_random_points: int = 2_000_000
    """Random initial points (paper: 2M), half inside the lidar range and half beyond it."""
    random_points_per_lidar_point: Optional[float] = 0.5
    """Cap the random points at this many per lidar point so small scenes stay small (None: no cap)."""
    init_seed: int = 0
    """Seed of the initialisation (subsampling, random points, orientations)."""
    lpips_backbone: Optional[Path] = None
    """Torchvision AlexNet or VGG16 weights file for LPIPS at evaluation; without it LPIPS is skipped with a note."""
    lpips_net: str = "alex"
    """LPIPS backbone: ``alex`` (paper's PandaSet protocol) or ``vgg`` (its Waymo protocols)."""
    background_color: Tuple[float, float, float] = (0.5, 0.5, 0.5)
    """Initial learnable background colour behind all Gaussians."""


class IDSplatModel(Model):
    """Gaussians rendered by the project's rasterizer, decoded by the CNN with sensor embeddings."""

    config: IDSplatModelConfig

    def populate_modules(self) -> None:
        super().populate_modules()
        metadata = self.kwargs.get("metadata", {})
        scene = metadata["scene"]
        self.camera_names: List[str] = list(metadata["camera_names"])
        if metadata.get("test_mode", "val") == "val":
            self.gaussians = self._initial_gaussians(scene, metadata["split_images"])
        else:
            # ns-eval / ns-viewer: a checkpoint is loaded next (load_state_dict resizes), so the
            # initialisation (a KNN over millions of points at paper settings) would be wasted.
            self.gaussians = GaussianSet(0, self.config.feature_dim)
        self.sensor_embedding = nn.Embedding(len(self.camera_names), self.config.sensor_embedding_dim)
        nn.init.zeros_(self.sensor_embedding.weight)
        self.rgb_decoder = RGBDecoderCNN(
            self.config.feature_dim, self.config.sensor_embedding_dim, self.config.decoder_hidden,
            self.config.decoder_kernel, self.config.decoder_blocks,
        )
        self.background = nn.Parameter(torch.logit(torch.tensor(self.config.background_color).clamp(0.01, 0.99)))
        self.step = 0
        self._lpips = None

    def _initial_gaussians(self, scene, train_images) -> GaussianSet:
        init_cfg = InitConfig(
            max_lidar_points=self.config.max_lidar_points,
            num_random_points=self.config.num_random_points,
            points_per_lidar_point=self.config.random_points_per_lidar_point,
            seed=self.config.init_seed,
        )
        init = initial_points_from_scene(scene, init_cfg, lambda im: load_rgb(im, 0.5), images=train_images)
        CONSOLE.print(f"IDSplat: {len(init.means)} initial Gaussians ({int(init.is_lidar.sum())} from lidar)")
        return GaussianSet.from_points(init, self.config.feature_dim, opacity=init_cfg.initial_opacity, seed=self.config.init_seed)

    # --- training plumbing -------------------------------------------------------------------
    def get_training_callbacks(self, training_callback_attributes: TrainingCallbackAttributes) -> List[TrainingCallback]:
        def set_step(step: int) -> None:
            self.step = step

        return [TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], set_step)]

    def get_param_groups(self) -> Dict[str, List[nn.Parameter]]:
        g = self.gaussians
        return {
            "means": [g.means],
            "scales": [g.scales],
            "quats": [g.quats],
            "opacities": [g.opacities],
            "features_rgb": [g.features_rgb],
            "features": [g.features],
            "decoders": list(self.rgb_decoder.parameters()) + [self.background],
            "sensor_embeddings": list(self.sensor_embedding.parameters()),
        }

    def load_state_dict(self, state_dict, strict: bool = True, **kwargs):  # type: ignore[override]
        num = state_dict["gaussians.means"].shape[0]
        if num != self.gaussians.num:
            self.gaussians.resize_(num)
        self.step = 10**9  # a loaded model renders at full resolution
        return super().load_state_dict(state_dict, strict=strict, **kwargs)

    # --- rendering ----------------------------------------------------------------------------
    def _camera_inputs(self, camera: Cameras, downscale: int) -> tuple[Tensor, Tensor, int, int]:
        c2w = camera.camera_to_worlds[0].to(self.device)  # [3, 4] OpenGL axes
        R = c2w[:3, :3] @ OPENGL_TO_OPENCV.to(c2w)
        t = c2w[:3, 3]
        viewmat = torch.eye(4, device=self.device)
        viewmat[:3, :3] = R.T
        viewmat[:3, 3] = -R.T @ t
        width, height = int(camera.width[0, 0]) // downscale, int(camera.height[0, 0]) // downscale
        sx, sy = width / float(camera.width[0, 0]), height / float(camera.height[0, 0])
        K = torch.tensor(
            [[float(camera.fx[0, 0]) * sx, 0.0, float(camera.cx[0, 0]) * sx],
             [0.0, float(camera.fy[0, 0]) * sy, float(camera.cy[0, 0]) * sy],
             [0.0, 0.0, 1.0]],
            device=self.device,
        )
        return viewmat[None], K[None], width, height

    def _downscale(self) -> int:
        return resolution_downscale(self.step, self.config.resolution_schedule) if self.training else 1

    def get_outputs(self, camera: Cameras) -> Dict[str, Tensor]:  # type: ignore[override]
        if not isinstance(camera, Cameras) or camera.shape[0] != 1:
            raise ValueError("IDSplatModel renders one Cameras object of one camera at a time")
        viewmat, K, width, height = self._camera_inputs(camera, self._downscale())
        g = self.gaussians.activated()
        feats = torch.cat([g["colors"], g["features"]], dim=1)
        out = rasterize_camera(
            g["means"], g["quats"], g["scales"], g["opacities"], feats, viewmat, K, width, height,
            # Per-instance maps cost a compositing channel each; the static model has none.
            instance_ids=self.gaussians.instance_ids if bool((self.gaussians.instance_ids > 0).any()) else None,
        )
        alpha = out.alpha[0]
        background = torch.sigmoid(self.background)
        base = out.features[0, ..., :3] + (1 - alpha) * background
        sensor = 0
        if camera.metadata is not None and "sensor_idx" in camera.metadata:
            sensor = int(camera.metadata["sensor_idx"].reshape(-1)[0])
        emb = self.sensor_embedding.weight[sensor : sensor + 1]
        rgb = self.rgb_decoder(base[None], out.features[:, ..., 3:], emb)[0]
        return {
            "rgb": rgb,
            "depth": out.depth[0],
            "accumulation": alpha,
            "instance_id": out.instance_id[0, ..., None].float(),  # -1 where nothing is rendered
            "background": background,
        }

    @torch.no_grad()
    def get_outputs_for_camera(self, camera: Cameras, obb_box=None) -> Dict[str, Tensor]:  # type: ignore[override]
        return self.get_outputs(camera.to(self.device))

    # --- losses and metrics -------------------------------------------------------------------
    def _gt_image(self, batch: Dict, like: Tensor) -> Tensor:
        gt = batch["image"].to(self.device)
        if gt.dtype == torch.uint8:
            gt = gt.float() / 255.0
        gt = gt[..., :3]
        if gt.shape[:2] != like.shape[:2]:
            gt = F.interpolate(gt.permute(2, 0, 1)[None], size=like.shape[:2], mode="area")[0].permute(1, 2, 0)
        return gt

    def get_metrics_dict(self, outputs, batch) -> Dict[str, Tensor]:
        gt = self._gt_image(batch, outputs["rgb"])
        return {"psnr": psnr(outputs["rgb"].detach(), gt), "gaussian_count": torch.tensor(float(self.gaussians.num))}

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> Dict[str, Tensor]:
        pred = outputs["rgb"]
        gt = self._gt_image(batch, pred)
        l1 = (pred - gt).abs().mean()
        s = ssim(pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])
        lam = self.config.ssim_lambda
        return {"main_loss": (1 - lam) * l1 + lam * (1 - s)}

    def get_image_metrics_and_images(self, outputs, batch) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        pred = outputs["rgb"].clamp(0, 1)
        gt = self._gt_image(batch, pred)
        metrics: Dict[str, float] = {
            "psnr": float(psnr(pred, gt)),
            "ssim": float(ssim(pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])),
        }
        mask = batch.get("dynamic_mask")
        if mask is not None and bool(mask.any()):
            metrics["dpsnr"] = float(psnr(pred, gt, mask.to(self.device)[..., 0]))
        lpips = self._lpips_metric()
        if lpips is not None:
            metrics["lpips"] = float(lpips(pred, gt))
        images = {
            "img": torch.cat([gt, pred], dim=1),
            "depth": colormaps.apply_depth_colormap(outputs["depth"], accumulation=outputs["accumulation"]),
        }
        return metrics, images

    def _lpips_metric(self):
        if self.config.lpips_backbone is None:
            return None
        if self._lpips is None:
            from idsplat_ns.eval.lpips import LPIPS

            self._lpips = LPIPS.from_files(self.config.lpips_backbone, net=self.config.lpips_net).to(self.device)
        return self._lpips
