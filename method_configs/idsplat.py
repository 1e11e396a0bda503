"""The methods ``idsplat`` (the paper's settings), ``idsplat-medium``, ``idsplat-fast`` (CPU-sized
presets) and ``idsplat-preview`` (a quicker look), registered with nerfstudio through entry points
in pyproject.toml (dataparsers: dataparsers.py).

The speed/accuracy trade is a preset: ``idsplat-fast`` keeps the model and losses but trains
fewer steps with a proportionally shorter resolution schedule, fewer initial Gaussians and a lidar
batch every fourth step; ``idsplat-medium`` trains that model 3000 steps; ``idsplat-preview``
trains 1000 steps from half as many initial Gaussians. The points were chosen on the measured
front of docs/reports/2026-11-27-pareto.md (``bench/pareto.py``).
"""

from __future__ import annotations

import torch
from nerfstudio.configs.base_config import MachineConfig, ViewerConfig
from nerfstudio.plugins.types import MethodSpecification

import idsplat_ns._compat.startup as _startup
from idsplat_ns.errors import install_excepthook
from idsplat_ns.cli.command_failures import explain_checkpoint_load, explain_export, remove_export_folder
from idsplat_ns.nerfstudio.datamanager import IDSplatDataManagerConfig
from idsplat_ns.nerfstudio.model import IDSplatModelConfig
from idsplat_ns.nerfstudio.optimizers import FusedAdamOptimizerConfig
from idsplat_ns.nerfstudio.pipeline import IDSplatPipelineConfig
from idsplat_ns.nerfstudio.schedulers import ExponentialDecaySchedulerConfig
from idsplat_ns.nerfstudio.trainer_config import IDSplatTrainerConfig

_startup.install()
install_excepthook(explain_checkpoint_load, explain_export, cleanups=(remove_export_folder,))


def _device() -> str:
    """CUDA when present, else the CPU: no flag to remember."""
    return "cuda" if torch.cuda.is_available() else "cpu"


def _optimizers(max_steps: int, warmup_scale: float = 1.0) -> dict:
    """The paper's parameter groups and schedules (supplementary Table 10)."""

    def group(lr: float, lr_final: float | None = None, warmup: int = 0) -> dict:
        sched = None
        if lr_final is not None or warmup:
            sched = ExponentialDecaySchedulerConfig(
                lr_final=lr_final if lr_final is not None else lr,
                warmup_steps=int(warmup * warmup_scale), max_steps=max_steps,
            )
        return {"optimizer": FusedAdamOptimizerConfig(lr=lr, eps=1e-15), "scheduler": sched}

    return {
        "means": group(1.6e-4, 1.6e-6),
        "opacities": group(5e-2),
        "scales": group(5e-3),
        "quats": group(1e-3),
        "features_rgb": group(2.5e-3),
        "features": group(2.5e-3),
        "decoders": group(1e-3, 1e-3, warmup=500),
        "sensor_embeddings": group(1e-3, 1e-3, warmup=500),
        # The lidar head is a decoder (Table 10's "Decoders" row); absent in camera-only scenes.
        "lidar_head": group(1e-3, 1e-3, warmup=500),
        # Table 10's "Cam. time to center": a learnable time offset per camera (only with instances).
        "camera_time_offsets": group(2e-4, 1e-7, warmup=10_000),
        # Per-image colour, camera calibration and per-image pose (--pipeline.model.exposure,
        # --pipeline.model.camera-refinement, --pipeline.model.pose-refinement; not in the paper). A per-image
        # parameter moves only on the steps that draw its image, hence the larger rate.
        "exposure": group(1e-3, 1e-4),
        "camera_refinement": group(2e-4, 2e-5),
        "pose_refinement": group(1e-3, 1e-4),
        # Instance trajectories (absent in static scenes; nerfstudio ignores unused groups).
        "trajectory_positions": group(1e-3, 1e-4, warmup=1500),
        "trajectory_rotations": group(5e-5, 1e-6, warmup=1500),
        # Not in the paper: the deformation of pedestrians and cyclists (off unless enabled).
        "deformation": group(1e-3, 1e-4),
    }


# Initial Gaussians of the CPU presets: (random points, lidar points at most).
FAST_INITIAL_POINTS = (20_000, 60_000)
PREVIEW_INITIAL_POINTS = (10_000, 30_000)


def make_trainer_config(
    method_name: str,
    max_steps: int,
    resolution_schedule: tuple,
    fast: bool,
    initial_points: tuple[int, int] = FAST_INITIAL_POINTS,
) -> IDSplatTrainerConfig:
    """A trainer configuration: the paper's (``fast=False``) or a CPU-sized one with
    ``initial_points`` (random points, lidar points at most) and a lidar batch every fourth step."""
    model = IDSplatModelConfig(resolution_schedule=resolution_schedule)
    if fast:
        model.num_random_points, model.max_lidar_points = initial_points
        # A lidar batch costs more than a full-resolution camera step on the CPU (0.5 s against
        # 0.35 s, docs/lidar.md): every fourth step keeps `make demo` near 10 minutes (the paper:
        # every step, which `idsplat` keeps).
        model.lidar.every_n_steps = 4
    # IDSplatTrainerConfig: nerfstudio's, with the settings validated before the run folder is written.
    return IDSplatTrainerConfig(
        method_name=method_name,
        steps_per_eval_image=max(max_steps // 10, 100),
        steps_per_eval_batch=0,
        # A checkpoint every fifth of the run: a killed run resumes from it (idsplat_ns/nerfstudio/trainer.py).
        steps_per_save=max(max_steps // 5, 100),
        steps_per_eval_all_images=10**9,  # held-out evaluation is ns-eval's job
        max_num_iterations=max_steps,
        mixed_precision=False,
        machine=MachineConfig(device_type=_device()),
        pipeline=IDSplatPipelineConfig(datamanager=IDSplatDataManagerConfig(), model=model),
        optimizers=_optimizers(max_steps, warmup_scale=max_steps / 30_000 if fast else 1.0),
        # ns-train returns when training ends; --viewer.quit-on-train-completion False keeps the viewer up.
        viewer=ViewerConfig(num_rays_per_chunk=1 << 15, quit_on_train_completion=True),
        vis="viewer",
    )


idsplat_method = MethodSpecification(
    config=make_trainer_config("idsplat", 30_000, (3000, 6000), fast=False),
    description="IDSplat: instance-decomposed Gaussian splatting for driving scenes (paper settings).",
)

idsplat_fast_method = MethodSpecification(
    config=make_trainer_config("idsplat-fast", 1500, (300, 700), fast=True),
    description="IDSplat, CPU-sized preset: 1500 steps, short resolution schedule, fewer initial Gaussians.",
)

idsplat_medium_method = MethodSpecification(
    config=make_trainer_config("idsplat-medium", 3000, (600, 1400), fast=True),
    description="IDSplat, CPU-sized preset: idsplat-fast's model trained twice as long (3000 steps).",
)

idsplat_preview_method = MethodSpecification(
    config=make_trainer_config("idsplat-preview", 1000, (200, 466), fast=True, initial_points=PREVIEW_INITIAL_POINTS),
    description="IDSplat, quick-look preset: 1000 steps from half of idsplat-fast's initial Gaussians.",
)
