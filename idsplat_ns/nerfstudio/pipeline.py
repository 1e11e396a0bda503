"""IDSplat pipeline: the vanilla pipeline with an evaluation average that tolerates metrics only
some images have (DPSNR of a class needs moving objects of that class in view), plus the tracking
metrics per class, the per-object diagnosis (frames lost, distance to the ego, DPSNR of each
annotated moving road user), the render speed and the lidar metrics of the held-out sweeps. A metric the data
or the given files cannot support (LPIPS without weights, ray drop without drop labels) is absent
from ns-eval's JSON, and a ``<metric>_note`` line there says why."""

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

from idsplat_ns.data.tracks import ROAD_USER_CLASSES
from idsplat_ns.eval.lidar_evaluation import held_out_lidar_metrics, sweep_range_errors
from idsplat_ns.eval.lpips import LPIPS_NOTE
from idsplat_ns.eval.metric_average import average_image_metrics
from idsplat_ns.eval.metric_plots import plot_lidar_error_by_range, plot_per_image
from idsplat_ns.eval.object_diagnosis import diagnose_objects, diagnosis_summary
from idsplat_ns.eval.object_plots import plot_object_timeline
from idsplat_ns.eval.trajectory_eval import ground_truth_positions, predicted_positions, tracking_metrics
from idsplat_ns.eval.trajectory_plots import plot_position_errors, plot_scene_top_view
from idsplat_ns.model.lidar_supervision import sweeps_of_frames
from idsplat_ns.nerfstudio.model_inputs import instance_inputs, split_data

CONSOLE = Console()


@dataclass
class IDSplatPipelineConfig(VanillaPipelineConfig):
    """Pipeline of the IDSplat method."""

    _target: Type = field(default_factory=lambda: IDSplatPipeline)


class IDSplatPipeline(VanillaPipeline):
    """Vanilla pipeline whose image-metric average handles per-image optional metrics and adds
    the tracking metrics of the instance trajectories and the render speed."""

    def _tracking_metrics(self) -> dict:
        """CLEAR-MOT of the (optimised) trajectories against the ground truth, when both exist:
        vehicles (the headline), each other class and all moving road users, with their counts."""
        trajectories = self.model.scene_model.trajectories
        scene = self.datamanager.scene
        if trajectories is None or not any(t.moving for t in scene.tracks):
            return {}

        with torch.no_grad():
            return tracking_metrics(scene, trajectories.positions_at)

    def _object_diagnosis(self, object_errors: dict) -> list:
        """One record per annotated moving road user: frames tracked and lost by the (optimised)
        trajectories at 2 m, its distance to the ego, its DPSNR over the held-out images
        (``object_errors``: ``{track_id: (squared error, pixels)}`` summed over them)."""
        scene = self.datamanager.scene
        if not any(t.moving for t in scene.tracks):
            return []
        trajectories = self.model.scene_model.trajectories
        with torch.no_grad():
            return diagnose_objects(scene, trajectories.positions_at if trajectories is not None else (lambda t: {}),
                                    object_errors=object_errors)  # fmt: skip

    def _held_out_sweeps(self) -> list:
        """Lidar sweeps of the evaluation frames (none for camera-only models or scenes)."""
        if getattr(self.model, "lidar", None) is None:
            return []

        frames = split_data(self.datamanager.eval_dataset.metadata).frames
        return sweeps_of_frames(self.datamanager.scene, frames)

    def _lidar_metrics(self, progress: Progress, range_errors: list) -> tuple[dict, Optional[str]]:
        """Table-2 lidar metrics averaged over the held-out sweeps, and a note on what the data
        cannot measure (the ray-drop accuracy without drop labels). Appends each sweep's
        (measured range, absolute error) to ``range_errors`` for the plot."""
        sweeps = self._held_out_sweeps()
        if not sweeps:
            return {}, None
        task = progress.add_task("[green]Evaluating held-out lidar sweeps...", total=len(sweeps))
        threshold = self.model.config.lidar.drop_threshold
        return held_out_lidar_metrics(self.datamanager.scene, sweeps, self.model.render_lidar_sweep, threshold,
                                      lambda: progress.advance(task),
                                      lambda rendered: range_errors.append(sweep_range_errors(rendered, threshold)))

    def _write_plots(self, folder: Path, per_image: list, range_errors: list, objects: list) -> list[str]:
        """Plots of the evaluation (ns-eval with --render-output-path only): the top view of the
        learned trajectories with their IDs, the annotated moving road users and the ego path, each
        instance's position error over time, PSNR / DPSNR per held-out image and the held-out lidar
        range error by distance. Ground truth: the annotated moving road users of every class."""
        scene = self.datamanager.scene
        trajectories = self.model.scene_model.trajectories
        with torch.no_grad():
            pred = predicted_positions(scene, trajectories.positions_at) if trajectories is not None else {}
        gt = ground_truth_positions(scene, groups=ROAD_USER_CLASSES)
        title = f"{scene.name}: top view"
        top = plot_scene_top_view(gt, pred, scene.ego_poses[:, :3, 3], folder / "plots" / "trajectories_top.png", title)
        plots = [top]
        if pred:
            plots.append(plot_position_errors(gt, pred, folder / "plots" / "position_errors.png",
                                              f"{scene.name}: instance position error against the nearest annotated track"))
        plots.append(plot_per_image(per_image, folder / "plots" / "per_image_psnr.png", f"{scene.name}: held-out images"))
        if objects:
            plots.append(plot_object_timeline(objects, folder / "plots" / "objects_timeline.png",
                                              f"{scene.name}: annotated moving road users, frame by frame"))
        ranges = np.concatenate([r for r, _ in range_errors]) if range_errors else np.zeros(0)
        if ranges.size:
            errors = np.concatenate([e for _, e in range_errors])
            plots.append(plot_lidar_error_by_range(ranges, errors, folder / "plots" / "lidar_error_by_range.png",
                                                   f"{scene.name}: held-out lidar sweeps"))
        return [str(p) for p in plots]

    def get_average_image_metrics(self, data_loader, image_prefix: str, step: Optional[int] = None,
                                  output_path: Optional[Path] = None, get_std: bool = False):
        self.eval()
        per_image = []
        object_errors: dict = {}  # track_id -> [squared error, pixels] over the held-out images
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
                # Only ns-eval reports the per-object diagnosis (the trainer's evaluations log scalars).
                for tid, (sse, count) in (self.model.object_pixel_errors(outputs, batch) if step is None else {}).items():
                    acc = object_errors.setdefault(tid, [0.0, 0])
                    acc[0], acc[1] = acc[0] + sse, acc[1] + count
                if output_path is not None:
                    for key, image in images.items():
                        arr = (image.detach().clamp(0, 1).cpu().numpy() * 255).astype(np.uint8)
                        Image.fromarray(arr).save(output_path / f"{image_prefix}_{key}_{idx:04d}.png")
                progress.advance(task)
            range_errors: list = []
            lidar, lidar_note = self._lidar_metrics(progress, range_errors)
        result = average_image_metrics(per_image, get_std)
        result.update(self._tracking_metrics())
        result.update(lidar)
        objects = self._object_diagnosis({k: tuple(v) for k, v in object_errors.items()}) if step is None else []
        if objects:  # ns-eval's JSON: which object was lost, when, how close (the trainer logs scalars only)
            result.update(diagnosis_summary(objects))
            result["objects"] = [r.as_dict() for r in objects]
        if output_path is not None and step is None:  # ns-eval writing renders: the plots go beside them
            result["plots"] = self._write_plots(output_path, per_image, range_errors, objects)
            CONSOLE.print(f"plots: {', '.join(result['plots'])}")
        if step is None:  # ns-eval's JSON says which protocol and instance source the result belongs to
            protocol = split_data(self.datamanager.train_dataparser_outputs.metadata).protocol
            result["protocol"] = protocol or "none (the dataparser's own split options)"
            inputs = instance_inputs(self.datamanager.train_dataset.metadata)
            result["instance_mode"] = inputs.mode
            tracks = inputs.tracks
            if tracks is not None and tracks.metadata.get("mask_source"):
                result["mask_source"] = tracks.metadata["mask_source"]
            corrections = self.model.camera_corrections()  # what the calibration and pose refinement learned
            if corrections:
                result["camera_corrections"] = corrections
        if step is None:  # notes only in ns-eval's JSON: the trainer logs metrics as scalars
            notes = {"lpips_note": LPIPS_NOTE if "lpips" not in result else None, "lidar_raydrop_note": lidar_note}
            for key, note in notes.items():
                if note is not None:
                    result[key] = note
                    CONSOLE.print(f"[yellow]note: {note}")
        self.train()
        return result
