"""Where the model's instances come from: the three modes of the method.

* ``self-supervised`` (default, the paper): masks -> lifting -> registration -> smoothing
  (:func:`idsplat_ns.instances.runner.run_preprocessing`), on the training frames only.
* ``oracle``: the dataset's annotated tracks (:mod:`idsplat_ns.instances.oracle`), the
  SplatAD-style upper bound, named as such.
* ``static``: no instances (the baseline without them).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Literal, Optional

from rich.console import Console

from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.masks.precomputed import PrecomputedMasksConfig
from idsplat_ns.instances.options import cli_option
from idsplat_ns.instances.oracle import oracle_instance_tracks
from idsplat_ns.instances.runner import PreprocessConfig, run_preprocessing
from idsplat_ns.instances.tracks import InstanceTracks

InstanceMode = Literal["self-supervised", "oracle", "static"]
CONSOLE = Console()


def ground_truth_masks(scene: Scene, config: PreprocessConfig) -> PreprocessConfig:
    """``masks.kind ground-truth``: the built-in street's own 2D instance masks as the mask folder
    (an ablation: perfect masks in place of a detector's). Other kinds are returned unchanged."""
    if config.masks.kind != "ground-truth":
        return config
    folder = None if scene.root is None else scene.root / "idsplat_extras" / "instance_masks"
    if folder is None or not folder.is_dir():
        raise IDSplatError(f"{cli_option('masks.kind')} ground-truth: {scene.root} has no idsplat_extras/instance_masks; "
                           "only the built-in street (idsplat-synth) has ground-truth masks")
    CONSOLE.print(f"[yellow]ablation: ground-truth 2D instance masks of the built-in street ({cli_option('masks.kind')} ground-truth), not a detector's")
    pre = PrecomputedMasksConfig(mask_dir=folder, instances_json=folder.parent / "instances.json")
    return replace(config, masks=replace(config.masks, kind="precomputed", precomputed=pre))


def instance_tracks_for_mode(
    scene: Scene,
    mode: InstanceMode,
    train_frames: set[int],
    preprocess: PreprocessConfig,
    cache_dir: Path,
) -> Optional[InstanceTracks]:
    """The instance tracks the model starts from (None in static mode)."""
    if mode == "static":
        return None
    if not scene.has_lidar:
        where = scene.root if scene.root is not None else scene.name
        raise IDSplatError(
            f"{where}: no lidar loaded, and instance mode {mode!r} needs lidar points (instances are lifted to them); "
            "use data with lidar (and not --load-lidar False) or --pipeline.datamanager.instance-mode static"
        )
    train_scene = scene.subset(train_frames)
    if mode == "oracle":
        CONSOLE.print("[bold]Oracle mode: instance tracks from the dataset's annotations (an upper bound, not the method)")
        return oracle_instance_tracks(train_scene)
    if mode != "self-supervised":
        raise ValueError(f"unknown instance mode {mode!r}")
    config = ground_truth_masks(scene, preprocess)
    tracks = run_preprocessing(train_scene, config, cache_dir, progress=True, verbose=True).tracks
    if preprocess.masks.kind == "ground-truth":
        tracks.metadata["mask_source"] = "ground-truth (ablation)"
    return tracks
