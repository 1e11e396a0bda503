"""The IDSplat nerfstudio model: static and per-instance Gaussians with learnable trajectories,
rendered at each camera's time, decoded by the small CNN with sensor embeddings, densified by
MCMC. The maths lives in :mod:`idsplat_ns.model` (no nerfstudio); this is the adapter.

Loss: 0.8 L1 + 0.2 (1 - SSIM) + the MCMC opacity/scale regularisers; resolution schedule 1/4,
1/2, full (paper: until steps 3000 and 6000). Scenes with lidar add, every (k-th) training step,
the lidar losses of a batch of rays from a training sweep (:mod:`idsplat_ns.model.lidar_supervision`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Dict, List, Literal, Optional, Tuple, Type

import numpy as np
import torch
import torch.nn.functional as F
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.models.base_model import Model, ModelConfig
from nerfstudio.utils import colormaps
from nerfstudio.utils.misc import step_check
from rich.console import Console
from torch import Tensor, nn

from idsplat_ns.data.images import load_rgb
from idsplat_ns.eval.image_metrics import colour_aligned, psnr, ssim
from idsplat_ns.eval.lpips import LPIPS
from idsplat_ns.eval.object_diagnosis import object_pixel_errors
from idsplat_ns.instances.static_conversion import StaticConversionConfig, convert_static_instances, static_threshold
from idsplat_ns.model.camera_refinement import ImagePoseCorrection, RigCorrection
from idsplat_ns.model.camera_shutter import ShutterLookup
from idsplat_ns.model.checkpoint_shapes import deformation_like, trajectories_like
from idsplat_ns.model.deformation import DeformationConfig, InstanceDeformation, deformable_instance_ids
from idsplat_ns.model.exposure import ImageExposure
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.initialisation import InitConfig, initial_points_from_scene
from idsplat_ns.model.instance_init import instance_initial_points
from idsplat_ns.model.instance_palette import instance_colors
from idsplat_ns.model.instance_visibility import render_camera_hiding
from idsplat_ns.model.lidar_supervision import LidarConfig, LidarSupervisor, SweepRender, render_sweep, sweeps_of_frames
from idsplat_ns.model.mcmc import MCMCConfig, MCMCDensifier, mcmc_regularisation
from idsplat_ns.model.path_time import PathClock
from idsplat_ns.model.scene_model import DecoderConfig, SceneModel
from idsplat_ns.model.scene_summary import SceneSummary, summarise, summary_lines, write_summary
from idsplat_ns.model.schedules import resolution_downscale
from idsplat_ns.model.trajectories import InstanceTrajectories
from idsplat_ns.nerfstudio.dataparser import OPENCV_TO_OPENGL
from idsplat_ns.nerfstudio.model_inputs import instance_inputs, split_data
from idsplat_ns.nerfstudio.camera_read import HostCamera, read_camera
from idsplat_ns.nerfstudio.render_guard import check_render_tools
from idsplat_ns.nerfstudio.viewer_controls import InstanceControls, in_viewer_render
from idsplat_ns.nerfstudio.viewer_scene import start_view
from idsplat_ns.ranges import NON_NEGATIVE, POSITIVE, UNIT, bounded

CONSOLE = Console()
GAUSSIAN_GROUPS = GaussianSet.PARAM_NAMES


@dataclass
class IDSplatModelConfig(ModelConfig):
    """IDSplat model options; defaults are the paper's."""

    _target: Type = field(default_factory=lambda: IDSplatModel)
    enable_collider: bool = False
    """Ray colliders are for ray-marching models; a rasterizer renders whole cameras."""
    decoder: DecoderConfig = field(default_factory=DecoderConfig)
    """Feature, embedding and CNN sizes of the camera path."""
    ssim_lambda: float = bounded(0.2, UNIT)
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
    refine_trajectories: bool = True
    """Optimise instance trajectories jointly with the Gaussians (False: the paper's ablation g)."""
    use_mcmc: bool = True
    """MCMC densification (relocation, growth to the cap, noise); False keeps the initial set."""
    mcmc: MCMCConfig = field(default_factory=MCMCConfig)
    """MCMC settings (paper / Kheradmand et al. defaults)."""
    cap_factor: float = bounded(3.0, POSITIVE)
    """Scene-sized Gaussian cap: this many times the initial count, at most ``mcmc.cap_max`` (paper 10M)."""
    lpips_backbone: Optional[Path] = None
    """Torchvision AlexNet or VGG16 weights file for LPIPS at evaluation; without it LPIPS is skipped with a note."""
    lpips_net: str = "alex"
    """LPIPS backbone: ``alex`` (paper's PandaSet protocol) or ``vgg`` (its Waymo protocols)."""
    background_color: Tuple[float, float, float] = bounded((0.5, 0.5, 0.5), UNIT)
    """Initial learnable background colour behind all Gaussians."""
    lidar: LidarConfig = field(default_factory=LidarConfig)
    """Lidar supervision (rays per step, cadence, loss weights); used only when the scene has lidar."""
    learn_camera_time_offsets: bool = True
    """Learn a time offset per camera (seconds, zero-initialised; only when instances exist)."""
    static_min_displacement: Optional[float] = None
    """Metres: an instance whose positions span less than this (parked, stopped all sequence) or
    that is seen in one frame is modelled as static Gaussians without a trajectory, whatever the
    instance mode. None: the threshold the instance preprocessing used when the tracks carry one
    (``--pipeline.datamanager.preprocess.static.min-displacement``), else 1 m (the paper's)."""
    rolling_shutter: bool = True
    """Render each recorded image with its rolling shutter where the data gives one (Waymo, the
    built-in street made with ``--rolling-shutter-ms``): each Gaussian is drawn where it is when its
    line is exposed. No effect on global-shutter data (PandaSet). False: the ablation."""
    deformation: DeformationConfig = field(default_factory=DeformationConfig)
    """Non-rigid instances: a time-dependent offset of each Gaussian of a pedestrian or cyclist."""
    view_directions: bool = True
    """View-dependent colour: the RGB decoder also takes each pixel's world-frame ray direction, as
    in SplatAD, whose decoder the paper adopts (False: the ablation; a checkpoint keeps the choice
    it was trained with)."""
    exposure: bool = True
    """Per-image affine colour (exposure drifting over a drive), learned at each training image and
    interpolated in time for its camera's other frames (:mod:`idsplat_ns.model.exposure`; not in the
    paper). On: on unseen streets it changes held-out PSNR by under 0.1 dB where nothing drifts and
    regains most of what a drift of gains 0.7-1.3 costs (docs/model.md). False: the paper's model."""
    exposure_prior: float = 0.1
    """Weight of the prior that keeps each image's colour transform near identity."""
    exposure_smoothness: float = bounded(0.0, NON_NEGATIVE)
    """Weight of the prior that keeps each image's colour transform near its camera's neighbours' interpolated; 0: none."""
    camera_refinement: bool = True
    """Refine each camera's calibration: a rotation and translation per camera, in its own frame,
    for all its images (:mod:`idsplat_ns.model.camera_refinement`; not in the paper). On: on unseen
    streets it changes held-out PSNR by under 0.1 dB on a perfect rig and regains most of what a
    camera turned by a degree costs (docs/model.md). False: the paper's model."""
    camera_refinement_prior: Tuple[float, float, float] = bounded((1e-3, 1.0, 0.05), POSITIVE)
    """Weight of the calibration prior, and the correction it expects: degrees, metres."""
    pose_refinement: bool = False
    """Refine each image's pose: a rotation and translation per training image, in its camera's
    frame, interpolated in time for the camera's other frames (:mod:`idsplat_ns.model.camera_refinement`)."""
    pose_refinement_prior: Tuple[float, float, float] = bounded((1e-3, 0.5, 0.1), POSITIVE)
    """Weight of the per-image pose prior, and the correction it expects: degrees, metres."""
    pose_refinement_smoothness: float = bounded(0.0, NON_NEGATIVE)
    """As ``exposure_smoothness``, for each image's pose correction (units of ``pose_refinement_prior``)."""
    camera_backend: Literal["auto", "gsplat", "torch"] = "auto"
    """Camera rasterizer: ``auto`` (gsplat on CUDA where it is installed, else the pure-torch tile
    rasterizer), ``gsplat`` (CUDA only; compiled on first use, minutes) or ``torch`` (any device:
    a GPU run with no time to compile gsplat). The image is the same up to float rounding."""


class IDSplatModel(Model):
    """nerfstudio adapter around :class:`~idsplat_ns.model.scene_model.SceneModel`."""

    config: IDSplatModelConfig

    def populate_modules(self) -> None:
        super().populate_modules()
        check_render_tools()  # ns-render without ffmpeg: one line now, not after loading and rendering
        metadata = self.kwargs.get("metadata", {})
        split, inputs = split_data(metadata), instance_inputs(metadata)
        scene = split.scene
        self.camera_names: List[str] = list(split.camera_names)
        tracks = inputs.tracks
        self.static_config = StaticConversionConfig(min_displacement=static_threshold(self.config.static_min_displacement, tracks))
        if tracks is not None:
            # Only what moves gets a trajectory: oracle flags and imported tracks are not filtered upstream.
            tracks = convert_static_instances(tracks, self.static_config)
        self.instance_tracks = tracks
        trajectories = None
        if tracks is not None and len(tracks.instances) > 0:
            trajectories = InstanceTrajectories.from_instance_tracks(tracks, refine=self.config.refine_trajectories)
        if inputs.training:
            gaussians = self._initial_gaussians(scene, split.images, tracks if trajectories is not None else None)
        else:
            # ns-eval / ns-viewer: a checkpoint is loaded next (load_state_dict resizes), so the
            # initialisation (a KNN over millions of points at paper settings) would be wasted.
            gaussians = GaussianSet(0, self.config.decoder.feature_dim)
        lidar_sweeps = sweeps_of_frames(scene, split.frames) if self.config.lidar.enabled else []
        self.num_lidar_sweeps = len(lidar_sweeps)
        # A camera without training images would keep an untrained (zero) embedding: it gets none.
        self.used_cameras = {im.camera for im in split.images}
        self.scene_model = SceneModel(
            gaussians, len(self.camera_names), self.config.decoder, trajectories, self.config.background_color,
            lidar_head_hidden=self.config.lidar.head_hidden if lidar_sweeps else None,
            camera_time_offsets=self.config.learn_camera_time_offsets,
            embedded_sensors=[i for i, name in enumerate(self.camera_names) if name in self.used_cameras],
            view_directions=self.config.view_directions, deformation=self._deformation(trajectories, tracks),
            camera_backend=self.config.camera_backend,
        )
        self.shutters = ShutterLookup(scene.images, self.camera_names) if self.config.rolling_shutter else None
        # Knots at the training images (a checkpoint brings its own: load_state_dict).
        self.exposure = ImageExposure.for_images(split.images, self.camera_names) if self.config.exposure else None
        self.rig_correction = RigCorrection(len(self.camera_names)) if self.config.camera_refinement else None
        self.pose_correction = (ImagePoseCorrection.for_images(split.images, self.camera_names)
                                if self.config.pose_refinement else None)
        self.lidar = LidarSupervisor(lidar_sweeps, self.config.lidar, seed=self.config.init_seed) if lidar_sweeps else None
        cap = min(self.config.mcmc.cap_max, int(self.config.cap_factor * max(gaussians.num, 1)))
        self.mcmc_config = replace(self.config.mcmc, cap_max=cap)
        self.densifier = MCMCDensifier(self.mcmc_config, seed=self.config.init_seed) if self.config.use_mcmc else None
        # Render times: nerfstudio's viewer gives times in [0, 1] over the sequence.
        self.time_start = float(scene.frame_times[0])
        self.time_span = max(float(scene.frame_times[-1] - scene.frame_times[0]), 1e-6)
        # Cameras without a time (ns-render's interpolated paths) get one from where they are.
        by_sensor: Dict[str, list] = {}
        for im in scene.images:
            by_sensor.setdefault(im.camera, []).append(im)
        self.path_clock = PathClock([np.stack([im.camera_to_world[:3, 3] for im in ims]) for ims in by_sensor.values()],
                                    [np.array([im.time for im in ims]) for ims in by_sensor.values()])
        self._noted_missing_time = False
        # The viewer's instance panel (nerfstudio finds it as a ViewerControl attribute).
        self.viewer_controls = InstanceControls(self, start_view(scene))
        self.step = 0
        self._lpips = None
        self.instance_mode = str(inputs.mode)
        if inputs.training:
            CONSOLE.print("[bold]IDSplat models:[/bold]\n  " + "\n  ".join(summary_lines(self.scene_summary())), soft_wrap=True)

    def _deformation(self, trajectories, tracks) -> Optional[InstanceDeformation]:
        """The deformation of the instances of the configured classes (None: off, or none of them)."""
        cfg = self.config.deformation
        if not cfg.enabled or trajectories is None:
            return None
        ids = deformable_instance_ids(tracks, tuple(cfg.classes))
        if not ids:
            return None
        return InstanceDeformation(trajectories.frame_times.cpu().numpy(), np.array(ids), cfg.latent_dim, cfg.hidden,
                                   cfg.position_freqs, seed=self.config.init_seed)

    def scene_summary(self, step: Optional[int] = None) -> SceneSummary:
        """What is modelled and why (cameras, lidar, instances, Gaussians and parameters per group)."""
        sm = self.scene_model
        return summarise(
            camera_names=self.camera_names, used_cameras=self.used_cameras, lidar_sweeps=self.num_lidar_sweeps,
            lidar_head=sm.lidar_head, instance_mode=self.instance_mode, tracks=self.instance_tracks,
            trajectories=sm.trajectories, static_config=self.static_config, instance_ids=self.gaussians.instance_ids,
            groups=self.get_param_groups(), embedding=sm.sensor_embedding, camera_time_offset=sm.camera_time_offset,
            step=step, deformation=sm.deformation,
        )

    def _initial_gaussians(self, scene, train_images, tracks) -> GaussianSet:
        init_cfg = InitConfig(
            max_lidar_points=self.config.max_lidar_points,
            num_random_points=self.config.num_random_points,
            points_per_lidar_point=self.config.random_points_per_lidar_point,
            seed=self.config.init_seed,
        )
        def load(im):
            return load_rgb(im, 0.5)

        if tracks is None:
            init = initial_points_from_scene(scene, init_cfg, load, images=train_images)
            ids = None
        else:
            init = instance_initial_points(scene, tracks, init_cfg, load, images=train_images)
            ids = init.instance_ids
        g = GaussianSet.from_points(init, self.config.decoder.feature_dim, opacity=init_cfg.initial_opacity, seed=self.config.init_seed)
        if ids is not None:
            g.instance_ids.copy_(torch.from_numpy(ids).long())
        n_inst = 0 if ids is None else int((ids > 0).sum())
        CONSOLE.print(f"IDSplat: {g.num} initial Gaussians ({int(init.is_lidar.sum())} from lidar, {n_inst} on instances)")
        return g

    @property
    def gaussians(self) -> GaussianSet:
        return self.scene_model.gaussians

    # --- training plumbing -------------------------------------------------------------------
    def get_training_callbacks(self, attrs: TrainingCallbackAttributes) -> List[TrainingCallback]:
        def set_step(step: int) -> None:
            self.step = step

        callbacks = [TrainingCallback([TrainingCallbackLocation.BEFORE_TRAIN_ITERATION], set_step)]
        if self.densifier is not None and attrs.optimizers is not None:
            optimizers = attrs.optimizers.optimizers

            def densify(step: int) -> None:
                lr_means = optimizers["means"].param_groups[0]["lr"]
                self.densifier.step(step, self.gaussians, {k: optimizers[k] for k in GAUSSIAN_GROUPS}, lr_means)

            callbacks.append(TrainingCallback([TrainingCallbackLocation.AFTER_TRAIN_ITERATION], densify))
        trainer = attrs.trainer
        if trainer is not None and getattr(trainer, "base_dir", None) is not None:
            # The run folder, beside nerfstudio_models/ (not in it: nerfstudio's loaders read every
            # name there as step-N.ckpt, so any other file breaks ns-eval, ns-viewer and resuming).
            folder = Path(trainer.base_dir)
            write_summary(self.scene_summary(), folder)  # before training: what is modelled
            last = getattr(trainer, "_start_step", 0) + trainer.config.max_num_iterations - 1

            def rewrite_summary(step: int) -> None:
                # The trainer saves at these steps: the counts then match the checkpoint beside them.
                if step_check(step, trainer.config.steps_per_save) or step == last:
                    write_summary(self.scene_summary(step), folder)

            # After densify (registered first): MCMC changes the Gaussian counts.
            callbacks.append(TrainingCallback([TrainingCallbackLocation.AFTER_TRAIN_ITERATION], rewrite_summary))
        return callbacks

    def get_param_groups(self) -> Dict[str, List[nn.Parameter]]:
        g, sm = self.gaussians, self.scene_model
        groups = {name: [getattr(g, name)] for name in GAUSSIAN_GROUPS}
        groups["decoders"] = list(sm.rgb_decoder.parameters()) + [sm.background]
        groups["sensor_embeddings"] = list(sm.sensor_embedding.parameters())
        if sm.lidar_head is not None:
            groups["lidar_head"] = list(sm.lidar_head.parameters())
        if sm.camera_time_offset is not None:
            groups["camera_time_offsets"] = [sm.camera_time_offset]
        if sm.trajectories is not None:
            groups["trajectory_positions"] = list(sm.trajectories.position_parameters())
            groups["trajectory_rotations"] = list(sm.trajectories.rotation_parameters())
        if sm.deformation is not None:
            groups["deformation"] = list(sm.deformation.parameters())
        if self.exposure is not None:
            groups["exposure"] = [self.exposure.affine]
        if self.rig_correction is not None:
            groups["camera_refinement"] = list(self.rig_correction.parameters())
        if self.pose_correction is not None:
            groups["pose_refinement"] = list(self.pose_correction.parameters())
        return groups

    def load_state_dict(self, state_dict, strict: bool = True, **kwargs):  # type: ignore[override]
        num = state_dict["scene_model.gaussians.means"].shape[0]
        if num != self.gaussians.num:
            self.gaussians.resize_(num)
        self.step = 10**9  # a loaded model renders at full resolution
        rebuilt = trajectories_like(self.scene_model, state_dict, self.config.refine_trajectories, self.device)
        deformation_like(self.scene_model, state_dict, self.device)
        # The checkpoint's per-image colour (its knots, or none), whatever today's settings say,
        self.exposure = ImageExposure.like(state_dict, "exposure.").to(self.device) if "exposure.affine" in state_dict else None
        rig = state_dict.get("rig_correction.rotation")  # and its camera calibration correction
        self.rig_correction = RigCorrection(rig.shape[0]).to(self.device) if rig is not None else None
        self.pose_correction = (ImagePoseCorrection.like(state_dict, "pose_correction.").to(self.device)
                                if "pose_correction.rotation" in state_dict else None)  # and its per-image poses
        self.scene_model.decoder_like(state_dict, prefix="scene_model.")
        out = super().load_state_dict(state_dict, strict=strict, **kwargs)
        if rebuilt:
            self.scene_model.trajectories.reset_span_margin()
        return out

    # --- rendering ----------------------------------------------------------------------------
    def _camera_inputs(self, host: HostCamera, downscale: int) -> tuple[Tensor, Tensor, int, int]:
        c2w = host.camera_to_world  # [3, 4] OpenGL axes, on the host
        R = c2w[:3, :3] @ torch.as_tensor(OPENCV_TO_OPENGL[:3, :3]).to(c2w)  # the flip is its own inverse
        viewmat = torch.eye(4, dtype=c2w.dtype)
        viewmat[:3, :3] = R.T
        viewmat[:3, 3] = -R.T @ c2w[:3, 3]
        width, height = host.width // downscale, host.height // downscale
        sx, sy = width / host.width, height / host.height
        K = torch.tensor([[host.fx * sx, 0.0, host.cx * sx], [0.0, host.fy * sy, host.cy * sy], [0.0, 0.0, 1.0]])
        return viewmat.to(self.device), K.to(self.device), width, height

    def _render_time(self, host: HostCamera) -> Optional[float]:
        """Seconds since the sequence start: the image's own time, else the viewer's [0, 1] slider,
        else (a camera path without times) the time of the nearest point of the recorded camera
        paths (:class:`PathClock`), said once. Static scenes need no time."""
        if host.time_seconds is not None:
            return host.time_seconds
        if host.time_fraction is not None:
            return self.time_start + host.time_fraction * self.time_span
        if not self.scene_model.has_instances:
            return None
        if not self._noted_missing_time:
            CONSOLE.print("note: the camera path has no times; each camera is rendered at the time the recorded "
                          "drive passed nearest to it (moving vehicles included)", soft_wrap=True)
            self._noted_missing_time = True
        return self.path_clock.time_of(host.camera_to_world[:3, 3].double().numpy())

    @staticmethod
    def _read_one_camera(camera: Cameras) -> HostCamera:
        """The render inputs of a ``Cameras`` of one camera, in one device read (size, intrinsics,
        sensor and time)."""
        if not isinstance(camera, Cameras) or camera.shape[0] != 1:
            raise ValueError("IDSplatModel renders one Cameras object of one camera at a time")
        return read_camera(camera)

    def get_outputs(self, camera: Cameras) -> Dict[str, Tensor]:  # type: ignore[override]
        host = self._read_one_camera(camera)
        return self._render(host, self._render_time(host))

    def _render(self, host: HostCamera, time: Optional[float]) -> Dict[str, Tensor]:
        """The outputs of one camera at ``time`` (and, in a lidar training step, of a lidar batch)."""
        downscale = resolution_downscale(self.step, self.config.resolution_schedule) if self.training else 1
        viewmat, K, width, height = self._camera_inputs(host, downscale)
        sensor = host.sensor if host.sensor is not None else 0
        if self.rig_correction is not None and host.sensor is not None:  # recorded cameras only
            viewmat = self.rig_correction(viewmat, sensor)
        if self.pose_correction is not None and host.sensor is not None:
            viewmat = self.pose_correction(viewmat, sensor, time)
        shutter = self.shutters.at(sensor, time) if self.shutters is not None else None
        # Instances hidden in the viewer's panel are left out of the viewer's renders only.
        outputs = render_camera_hiding(self.scene_model, self.viewer_controls.hidden_now(),
                                       viewmat, K, width, height, time, sensor, shutter)
        if self.exposure is not None:
            outputs["rgb"] = self.exposure(outputs["rgb"], sensor, time)
        # Training steps only: the viewer renders under no_grad while the model is in training mode.
        if self.training and torch.is_grad_enabled() and self.lidar is not None and self.lidar.is_lidar_step(self.step):
            rays, sensor_to_world = self.lidar.sample(self.device)
            outputs.update(self.lidar.render_batch(self.scene_model, rays, sensor_to_world))
        return outputs

    def render_lidar_sweep(self, sweep) -> SweepRender:
        """Render a whole lidar sweep (range, intensity, ray-drop probability, alpha and the point
        cloud of the rays predicted as returned); used by evaluation."""
        return render_sweep(self.scene_model, sweep, self.config.lidar, self.device, seed=self.config.init_seed)

    @torch.no_grad()
    def get_outputs_for_camera(self, camera: Cameras, obb_box=None) -> Dict[str, Tensor]:  # type: ignore[override]
        """The rendered images plus ``instances`` (the ID map in the categorical instance colours)
        when the model has instances; viewer renders also get the panel's highlight. Only images
        [H, W, C]: ``ns-render dataset`` and the viewer write every output as one (the background
        colour [3] stays in the training outputs)."""
        host = self._read_one_camera(camera)  # read once: the render and the viewer's panel share the time
        time = self._render_time(host)
        outputs = {k: v for k, v in self._render(host, time).items() if v.dim() == 3}
        if self.scene_model.has_instances:
            outputs["instances"] = instance_colors(outputs["instance_id"][..., 0])
        if in_viewer_render():
            outputs = self.viewer_controls.after_render(outputs, time)
        return outputs

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
        losses = {"main_loss": (1 - lam) * l1 + lam * (1 - s)}
        if self.densifier is not None and self.training:
            losses["mcmc_reg"] = mcmc_regularisation(self.gaussians, self.mcmc_config)
        if "lidar_rays" in outputs and self.lidar is not None:
            losses.update(self.lidar.losses(outputs))
        if self.exposure is not None and self.training:
            losses["exposure_prior"] = self.config.exposure_prior * self.exposure.prior()
            if (smooth := self.config.exposure_smoothness) > 0:
                losses["exposure_smoothness"] = smooth * self.exposure.smoothness()
        if self.rig_correction is not None and self.training:
            weight, degrees, metres = self.config.camera_refinement_prior
            losses["camera_refinement_prior"] = weight * self.rig_correction.prior(degrees, metres)
        if self.pose_correction is not None and self.training:
            weight, degrees, metres = self.config.pose_refinement_prior
            losses["pose_refinement_prior"] = weight * self.pose_correction.prior(degrees, metres)
            if (smooth := self.config.pose_refinement_smoothness) > 0:
                losses["pose_refinement_smoothness"] = smooth * self.pose_correction.smoothness(degrees, metres)
        return losses

    def get_image_metrics_and_images(self, outputs, batch) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
        pred = outputs["rgb"].clamp(0, 1)
        gt = self._gt_image(batch, pred)
        metrics: Dict[str, float] = {
            "psnr": float(psnr(pred, gt)),
            "ssim": float(ssim(pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])),
            # Fitted to the scored image itself: for comparison with papers that report it, never instead of psnr.
            "psnr_colour_aligned": float(psnr(colour_aligned(pred, gt), gt)),
        }
        for key, mask in batch.items():
            # dynamic_mask: moving vehicles (the paper's DPSNR); dynamic_mask_<class> per class.
            if key.startswith("dynamic_mask") and bool(mask.any()):
                metrics["dpsnr" + key[len("dynamic_mask"):]] = float(psnr(pred, gt, mask.to(self.device)[..., 0]))
        lpips = self._lpips_metric()
        if lpips is not None:
            metrics["lpips"] = float(lpips(pred, gt))
        images = {
            "img": torch.cat([gt, pred], dim=1),
            "depth": colormaps.apply_depth_colormap(outputs["depth"], accumulation=outputs["accumulation"]),
        }
        if self.scene_model.has_instances:
            ids = outputs["instance_id"][..., 0].long()
            images["instances"] = instance_colors(ids)
        return metrics, images

    def camera_corrections(self) -> Dict[str, Dict[str, float]]:
        """Per camera, the learned pose corrections (ns-eval's JSON): its calibration's (degrees,
        metres) and the median over its training images of their own; empty when neither is on."""
        out: Dict[str, Dict[str, float]] = {}
        for name, corrections in [("calibration", self.rig_correction), ("image_pose_median", self.pose_correction)]:
            for camera, (deg, metres) in zip(self.camera_names, corrections.summary() if corrections else []):
                out.setdefault(camera, {}).update({f"{name}_deg": deg, f"{name}_m": metres})
        return out

    def object_pixel_errors(self, outputs, batch) -> Dict[str, Tuple[float, int]]:
        """Per annotated moving road user of an evaluation image: (squared error sum, pixels)."""
        if "object_map" not in batch or not batch["object_ids"]:
            return {}
        pred = outputs["rgb"].clamp(0, 1)
        return object_pixel_errors(pred, self._gt_image(batch, pred), batch["object_map"], batch["object_ids"])

    def _lpips_metric(self):
        if self.config.lpips_backbone is None:
            return None
        if self._lpips is None:
            self._lpips = LPIPS.from_files(self.config.lpips_backbone, net=self.config.lpips_net).to(self.device)
        return self._lpips

