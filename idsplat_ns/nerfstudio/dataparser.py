"""nerfstudio dataparsers: PandaSet (default: the built-in synthetic street) and Waymo.

Both turn a :class:`~idsplat_ns.data.scene.Scene` into nerfstudio ``Cameras`` (OpenGL axes, metres,
no rescaling) and hand the scene itself to the dataset and model through ``metadata``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Tuple, Type

import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras, CameraType
from nerfstudio.data.dataparsers.base_dataparser import DataParser, DataParserConfig, DataparserOutputs
from nerfstudio.data.scene_box import SceneBox

from idsplat_ns.data.images import undistorted_view
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.split import split_frames
from idsplat_ns.errors import IDSplatError

# OpenCV (x right, y down, z forward) -> OpenGL / nerfstudio (x right, y up, z back).
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class IDSplatDataParserConfig(DataParserConfig):
    """Options shared by the IDSplat dataparsers."""

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    data: Optional[Path] = None
    """Sequence to load; None uses the dataparser's default (the built-in street for PandaSet)."""
    cameras: Optional[Tuple[str, ...]] = None
    """Camera names to use (default: every camera of the sequence)."""
    start_frame: int = 0
    """First frame index to keep."""
    end_frame: Optional[int] = None
    """One past the last frame index to keep (None: to the end)."""
    downscale_factor: float = 1.0
    """Divide the image resolution by this (2 halves width and height)."""
    train_fraction: float = 0.5
    """Fraction of frames used for training; the rest, linearly spaced, are held out (paper: 0.5 on PandaSet)."""
    eval_every: Optional[int] = None
    """Hold out every k-th frame instead (overrides train_fraction), as some protocols do."""
    load_lidar: bool = True
    """Read lidar sweeps (initialisation; lidar supervision in the full model)."""

    def load_scene(self) -> Scene:
        """Parse the configured sequence; each dataset's config defines it."""
        raise NotImplementedError(f"{type(self).__name__} must define load_scene (use a dataset's config)")


@dataclass
class PandaSetDataParserConfig(IDSplatDataParserConfig):
    """A PandaSet sequence folder (``.../pandaset/001``); without ``--data``, the built-in street."""

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    builtin_preset: str = "small"
    """Preset of the built-in synthetic street used when no data is given (tiny, small, bench)."""
    builtin_seed: int = 0
    """Seed of the built-in synthetic street."""
    lidar_sensors: Tuple[int, ...] = (0,)
    """PandaSet lidars to use: 0 the spinning Pandar64, 1 the front PandarGT."""

    def load_scene(self) -> Scene:
        from idsplat_ns.data.pandaset import load_sequence

        path = self.data
        if path is None:
            from idsplat_ns.nerfstudio.builtin_scene import builtin_street

            path = builtin_street(self.builtin_preset, self.builtin_seed)
            self.data = path  # so that the saved config.yml reloads the same scene
        return load_sequence(
            path, cameras=self.cameras, start=self.start_frame, end=self.end_frame,
            load_lidar=self.load_lidar, lidar_sensors=self.lidar_sensors,
        )


@dataclass
class WaymoDataParserConfig(IDSplatDataParserConfig):
    """A Waymo v1 segment (``segment-*.tfrecord``) or a v2 root with ``context_name``."""

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    context_name: Optional[str] = None
    """v2 only: the segment context name inside the v2 root given as data."""
    train_fraction: float = 0.75
    """Fraction of frames used for training when eval_every is None."""
    eval_every: Optional[int] = 4
    """Hold out every 4th frame: the paper's AD-GS / SplatFlow protocols on Waymo (75% train)."""

    def load_scene(self) -> Scene:
        from idsplat_ns.data.waymo import load_segment

        if self.data is None:
            raise IDSplatError("--data is required for idsplat-waymo: a segment-*.tfrecord file or a v2 root with --context-name")
        kwargs = {"context_name": self.context_name} if self.context_name else {}
        return load_segment(
            self.data, cameras=list(self.cameras) if self.cameras else None, start=self.start_frame,
            end=self.end_frame, load_lidar=self.load_lidar, **kwargs,
        )


class IDSplatDataParser(DataParser):
    """Scene -> nerfstudio ``DataparserOutputs``, with the split of the configured protocol."""

    config: IDSplatDataParserConfig
    includes_time = True

    def __init__(self, config: IDSplatDataParserConfig):
        super().__init__(config=config)
        self._scene: Optional[Scene] = None

    @property
    def scene(self) -> Scene:
        if self._scene is None:
            self._scene = self.config.load_scene()
        return self._scene

    def _generate_dataparser_outputs(self, split: str = "train", **kwargs) -> DataparserOutputs:
        scene = self.scene
        train_idx, eval_idx = split_frames(scene.num_frames, self.config.train_fraction, self.config.eval_every)
        frame_ids = set(scene.frame_indices[train_idx if split == "train" else eval_idx].tolist())
        # Pinhole rasterizers: distorted images (Waymo) are undistorted on load, keeping their K.
        images = [undistorted_view(im) for im in scene.images if im.frame_index in frame_ids]
        if not images:
            raise IDSplatError(f"no {split} images: check --cameras, the frame range and the split options")
        camera_names = scene.camera_names
        scale = 1.0 / self.config.downscale_factor
        duration = max(float(scene.frame_times[-1] - scene.frame_times[0]), 1e-6)

        c2w = np.stack([im.camera_to_world @ OPENCV_TO_OPENGL for im in images])[:, :3, :4]
        intr = [im.intrinsics.scaled(scale) for im in images]
        cameras = Cameras(
            camera_to_worlds=torch.from_numpy(c2w).float(),
            fx=torch.tensor([[i.fx] for i in intr], dtype=torch.float32),
            fy=torch.tensor([[i.fy] for i in intr], dtype=torch.float32),
            cx=torch.tensor([[i.cx] for i in intr], dtype=torch.float32),
            cy=torch.tensor([[i.cy] for i in intr], dtype=torch.float32),
            width=torch.tensor([[i.width] for i in intr], dtype=torch.int64),
            height=torch.tensor([[i.height] for i in intr], dtype=torch.int64),
            camera_type=CameraType.PERSPECTIVE,
            # nerfstudio's viewer time slider runs over [0, 1]; seconds travel in metadata.
            times=torch.tensor([[(im.time - scene.frame_times[0]) / duration] for im in images], dtype=torch.float32),
            metadata={
                "sensor_idx": torch.tensor([[camera_names.index(im.camera)] for im in images], dtype=torch.int64),
                "time_seconds": torch.tensor([[im.time] for im in images], dtype=torch.float64),
            },
        )
        corners = [scene.ego_poses[:, :3, 3]]
        if scene.has_lidar:
            pts, _ = scene.all_lidar_points(max_points=200_000)
            corners.append(pts)
        allp = np.concatenate(corners)
        lo, hi = np.percentile(allp, 1, axis=0), np.percentile(allp, 99, axis=0)
        return DataparserOutputs(
            image_filenames=[im.image_path or Path(f"{im.camera}/{im.frame_index:04d}") for im in images],
            cameras=cameras,
            scene_box=SceneBox(aabb=torch.tensor(np.stack([lo, hi]), dtype=torch.float32)),
            metadata={
                "scene": scene,
                "split_images": images,
                "image_scale": scale,
                "camera_names": camera_names,
                "split": split,
            },
        )
