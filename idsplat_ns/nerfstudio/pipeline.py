"""IDSplat pipeline: the vanilla pipeline with an evaluation average that tolerates metrics only
some images have (DPSNR needs moving objects in view) and says what it could not compute, plus the
tracking metrics, the render speed and the lidar metrics of the held-out sweeps."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from time import time
from typing import Optional, Type

import numpy as np
import torch
from nerfstudio.pipelines.base_pipeline import VanillaPipeline, VanillaPipelineConfig
from PIL import Image
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from idsplat_ns.nerfstudio.dataset import frames_of_split

CONSOLE = Console()
LPIPS_NOTE = (
    "LPIPS not computed: no backbone weights given (nothing is downloaded); pass "
    "--pipeline.model.lpips-backbone <torchvision alexnet or vgg16 .pth file>"
)


@dataclass
class IDSplatPipelineConfig(VanillaPipelineConfig):
    """Pipeline of the IDSplat method."""

    _target: Type = field(default_factory=lambda: IDSplatPipeline)


class IDSplatPipeline(VanillaPipeline):
    """Vanilla pipeline whose image-metric average handles per-image optional metrics and adds
    the tracking metrics of the instance trajectories and the render speed."""

    def _tracking_metrics(self) -> dict:
        """CLEAR-MOT of the (optimised) trajectories against the ground truth, when both exist."""
        trajectories = self.model.scene_model.trajectories
        scene = self.datamanager.scene
        if trajectories is None or not any(t.moving for t in scene.tracks):
            return {}
        from idsplat_ns.eval.trajectory_eval import flatten_metrics, tracking_summary

        with torch.no_grad():
            observed = flatten_metrics(tracking_summary(scene, trajectories.positions_at))
            every = flatten_metrics(tracking_summary(scene, trajectories.positions_at, observed=None), prefix="all_")
        return {**observed, **every}

    def _held_out_sweeps(self) -> list:
        """Lidar sweeps of the evaluation frames (none for camera-only models or scenes)."""
        if getattr(self.model, "lidar", None) is None:
            return []
        from idsplat_ns.model.lidar_supervision import sweeps_of_frames

        frames = frames_of_split(self.datamanager.eval_dataset.metadata)
        return sweeps_of_frames(self.datamanager.scene, frames)

    def _lidar_metrics(self, progress: Progress) -> dict:
        """Table-2 lidar metrics averaged over the held-out sweeps (NaN sweeps left out)."""
        from idsplat_ns.model.lidar_supervision import sweep_metrics

        sweeps = self._held_out_sweeps()
        if not sweeps:
            return {}
        per_sweep = []
        task = progress.add_task("[green]Evaluating held-out lidar sweeps...", total=len(sweeps))
        for sweep in sweeps:
            per_sweep.append(sweep_metrics(self.model.render_lidar_sweep(sweep), self.model.config.lidar.drop_threshold))
            progress.advance(task)
        out: dict = {}
        for key in per_sweep[0]:
            values = np.array([m[key] for m in per_sweep], dtype=np.float64)
            finite = values[np.isfinite(values)]
            out[key] = float(finite.mean()) if finite.size else float("nan")
        out["lidar_num_sweeps"] = len(per_sweep)
        return out

    def _write_plots(self, folder: Path, per_image: list) -> list[str]:
        """Plots of the evaluation (ns-eval with --render-output-path only): the top view of the
        learned trajectories with their IDs, the annotated moving vehicles and the ego path, each
        instance's position error over time, and PSNR / DPSNR per held-out image."""
        from idsplat_ns.eval.metric_plots import plot_per_image
        from idsplat_ns.eval.trajectory_eval import ground_truth_positions, predicted_positions
        from idsplat_ns.eval.trajectory_plots import plot_position_errors, plot_scene_top_view

        scene = self.datamanager.scene
        trajectories = self.model.scene_model.trajectories
        with torch.no_grad():
            pred = predicted_positions(scene, trajectories.positions_at) if trajectories is not None else {}
        gt = ground_truth_positions(scene)
        title = f"{scene.name}: top view"
        top = plot_scene_top_view(gt, pred, scene.ego_poses[:, :3, 3], folder / "plots" / "trajectories_top.png", title)
        plots = [top]
        if pred:
            plots.append(plot_position_errors(gt, pred, folder / "plots" / "position_errors.png",
                                              f"{scene.name}: instance position error against the nearest annotated track"))
        plots.append(plot_per_image(per_image, folder / "plots" / "per_image_psnr.png", f"{scene.name}: held-out images"))
        return [str(p) for p in plots]

    def get_average_image_metrics(self, data_loader, image_prefix: str, step: Optional[int] = None,
                                  output_path: Optional[Path] = None, get_std: bool = False):
        self.eval()
        per_image = []
        if output_path is not None:
            output_path.mkdir(exist_ok=True, parents=True)
        with Progress(TextColumn("[progress.description]{task.description}"), BarColumn(), TimeElapsedColumn(),
                      MofNCompleteColumn(), transient=True) as progress:
            task = progress.add_task("[green]Evaluating held-out images...", total=len(data_loader))
            for idx, (camera, batch) in enumerate(data_loader):
                start = time()
                outputs = self.model.get_outputs_for_camera(camera=camera)
                metrics, images = self.model.get_image_metrics_and_images(outputs, batch)
                metrics["num_rays_per_sec"] = float(camera.height * camera.width) / (time() - start)
                per_image.append(metrics)
                if output_path is not None:
                    for key, image in images.items():
                        arr = (image.detach().clamp(0, 1).cpu().numpy() * 255).astype(np.uint8)
                        Image.fromarray(arr).save(output_path / f"{image_prefix}_{key}_{idx:04d}.png")
                progress.advance(task)
            lidar = self._lidar_metrics(progress)
        keys = list(dict.fromkeys(k for m in per_image for k in m))
        result: dict = {}
        for key in keys:
            values = torch.tensor([m[key] for m in per_image if key in m], dtype=torch.float64)
            result[key] = float(values.mean())
            if get_std:
                result[f"{key}_std"] = float(values.std()) if len(values) > 1 else 0.0
            if len(values) != len(per_image):
                result[f"{key}_num_images"] = len(values)
        result["num_images"] = len(per_image)
        result["render_mpix_per_s"] = result.pop("num_rays_per_sec") / 1e6
        result.pop("num_rays_per_sec_std", None)
        result.update(self._tracking_metrics())
        result.update(lidar)
        if output_path is not None and step is None:  # ns-eval writing renders: the plots go beside them
            result["plots"] = self._write_plots(output_path, per_image)
            CONSOLE.print(f"plots: {', '.join(result['plots'])}")
        if step is None:  # ns-eval's JSON says which protocol and instance source the result belongs to
            meta = self.datamanager.train_dataparser_outputs.metadata
            result["protocol"] = meta.get("protocol") or "none (the dataparser's own split options)"
            result["instance_mode"] = self.datamanager.train_dataset.metadata.get("instance_mode")
            tracks = self.datamanager.train_dataset.metadata.get("instance_tracks")
            if tracks is not None and tracks.metadata.get("mask_source"):
                result["mask_source"] = tracks.metadata["mask_source"]
        if "lpips" not in result and step is None:
            # Only for ns-eval's JSON (step None): the trainer logs metrics as scalars.
            result["lpips_note"] = LPIPS_NOTE
            CONSOLE.print(f"[yellow]note: {LPIPS_NOTE}")
        self.train()
        return result
