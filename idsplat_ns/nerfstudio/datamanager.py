"""Full-image datamanager over a Scene: images per camera, the scene (with its lidar sweeps) for
the model's initialisation, the instance tracks of the chosen mode, dynamic masks in
evaluation batches."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional, Tuple, Type

import torch
from rich.console import Console
from nerfstudio.data.datamanagers.full_images_datamanager import FullImageDatamanager, FullImageDatamanagerConfig

from idsplat_ns.instances.modes import InstanceMode, instance_tracks_for_mode
from idsplat_ns.instances.runner import PreprocessConfig
from idsplat_ns.instances.tracks_json import tracks_from_json
from idsplat_ns.nerfstudio.builtin_scene import instance_cache_dir
from idsplat_ns.nerfstudio.dataparser import AutoDataParserConfig, IDSplatDataParserUnion
from idsplat_ns.nerfstudio.dataset import IDSplatDataset
from idsplat_ns.nerfstudio.model_inputs import INSTANCES_KEY, InstanceInputs, split_data

CONSOLE = Console()


@dataclass
class IDSplatDataManagerConfig(FullImageDatamanagerConfig):
    """Datamanager of the IDSplat method."""

    _target: Type = field(default_factory=lambda: IDSplatDataManager)
    dataparser: IDSplatDataParserUnion = field(default_factory=AutoDataParserConfig)
    """Which dataset to read: a subcommand (idsplat-auto recognises --data; without it, the built-in street)."""
    cache_images: Literal["cpu", "gpu"] = "cpu"
    """Keep decoded images in CPU memory (moved to the device per step)."""
    cache_images_type: Literal["uint8", "float32"] = "uint8"
    """Cache images as uint8 (4x less memory; converted per step)."""
    eval_image_indices: Optional[Tuple[int, ...]] = None
    """Evaluate on every held-out image."""
    instance_mode: InstanceMode = "self-supervised"
    """Where instances come from: ``self-supervised`` (the paper: masks, lifting, registration,
    smoothing), ``oracle`` (the dataset's annotated tracks: an upper bound) or ``static`` (none)."""
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    """Instance preprocessing settings (self-supervised mode); paper defaults."""
    import_tracks: Optional[Path] = None
    """Start from instance tracks in a JSON file (written by ``idsplat-preprocess --export`` or another
    tracker, in the data's own frame and clock; docs/instances.md) instead of the instance mode's."""


class IDSplatDataManager(FullImageDatamanager[IDSplatDataset]):
    """nerfstudio's full-image datamanager with the IDSplat dataset and instance tracks."""

    config: IDSplatDataManagerConfig

    def __init__(self, config: IDSplatDataManagerConfig, device="cpu", test_mode="val", **kwargs):
        super().__init__(config, device=device, test_mode=test_mode, **kwargs)
        split = split_data(self.train_dataset.metadata)
        # The model initialises Gaussians only for training ("val"); ns-eval and ns-viewer
        # ("test"/"inference") load a checkpoint instead (stage caches make the tracks cheap then).
        if config.import_tracks is not None:
            tracks = tracks_from_json(config.import_tracks, split.scene.subset(split.frames))
            inputs = InstanceInputs("imported", tracks, test_mode)
            CONSOLE.print(f"[bold]instances: {len(tracks.instances)} imported from {config.import_tracks}")
        else:
            tracks = instance_tracks_for_mode(split.scene, config.instance_mode, split.frames, config.preprocess,
                                              instance_cache_dir(split.scene.name))
            inputs = InstanceInputs(config.instance_mode, tracks, test_mode)
        self.train_dataset.metadata[INSTANCES_KEY] = inputs

    @property
    def scene(self):
        return split_data(self.train_dataparser_outputs.metadata).scene

    def get_datapath(self) -> Path:
        """The sequence's folder: ``--data`` where given, else where the scene was read from (the
        built-in street's cache folder). nerfstudio's viewer opens it; a built-in-street run's
        config has no ``data``, and the viewer of ``make demo``'s run failed on ``None``."""
        data = self.config.dataparser.data
        if data is not None:
            return Path(data)
        root = self.scene.root
        return Path(root) if root is not None else Path.cwd()

    def _load_images(self, split, cache_images_device):
        # nerfstudio pins CPU-cached images, which needs an accelerator; when training on the CPU,
        # its "gpu" mode (cache on the training device, i.e. the CPU here) does the right thing.
        if torch.device(self.device).type == "cpu":
            cache_images_device = "gpu"
        return super()._load_images(split, cache_images_device)
