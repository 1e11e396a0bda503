"""nerfstudio dataparsers, as ``ns-train`` subcommands: ``idsplat-auto`` (the default: recognises
``--data``, the built-in street without it), ``idsplat-builtin``, ``idsplat-pandaset``, ``idsplat-waymo``.

All turn a :class:`~idsplat_ns.data.scene.Scene` into nerfstudio ``Cameras`` (OpenGL axes, metres,
no rescaling) and hand the scene itself to the dataset and model through ``metadata``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar, Optional, Tuple, Type

import numpy as np
import torch
import tyro
from nerfstudio.cameras.cameras import Cameras, CameraType
from nerfstudio.data.dataparsers.base_dataparser import DataParser, DataParserConfig, DataparserOutputs
from nerfstudio.data.scene_box import SceneBox
from rich.console import Console

from idsplat_ns.data.formats import DATAPARSER_SUBCOMMANDS, detect_data
from idsplat_ns.data.images import undistorted_view
from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.data.protocols import protocol_dataset, select_protocol
from idsplat_ns.data.scene import Scene, note_empty_sweeps
from idsplat_ns.data.split import split_frames
from idsplat_ns.data.waymo import load_segment
from idsplat_ns.data.waymo.memory import available_memory_bytes, check_fits, estimate_segment_memory
from idsplat_ns.data.waymo.v1 import read_v1
from idsplat_ns.errors import IDSplatError
from idsplat_ns.nerfstudio.builtin_scene import builtin_street
from idsplat_ns.nerfstudio.model_inputs import SPLIT_KEY, SplitData
from idsplat_ns.ranges import AT_LEAST_ONE, FRACTION, POSITIVE, Range, bounded

CONSOLE = Console()

# OpenCV (x right, y down, z forward) -> OpenGL / nerfstudio (x right, y up, z back).
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class IDSplatDataParserConfig(DataParserConfig):
    """Options shared by the IDSplat dataparsers."""

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    data: Optional[Path] = None
    """Sequence to load (each dataparser says what it takes)."""
    cameras: Optional[Tuple[str, ...]] = None
    """Camera names to use (default: every camera of the sequence)."""
    start_frame: int = bounded(0, Range(0, integer=True))
    """First frame index to keep."""
    end_frame: Optional[int] = bounded(None, AT_LEAST_ONE)
    """One past the last frame index to keep (None: to the end)."""
    downscale_factor: float = bounded(1.0, POSITIVE)
    """Divide the image resolution by this (2 halves width and height)."""
    train_fraction: float = bounded(0.5, FRACTION)
    """Fraction of frames used for training; the rest, linearly spaced, are held out (paper: 0.5 on PandaSet)."""
    eval_every: Optional[int] = bounded(None, Range(2, integer=True))
    """Hold out every k-th frame instead (overrides train_fraction), as some protocols do."""
    load_lidar: bool = True
    """Read lidar sweeps (initialisation; lidar supervision in the full model)."""
    protocol: Optional[str] = None
    """One of the paper's evaluation protocols (streetgs, notr-dynamic, pvg, view-density-25/50/75/100 on
    Waymo; pandaset-10): it sets the frames, cameras, resolution and split of the sequence (docs/data.md)."""

    def load_scene(self) -> Scene:
        """Parse the configured sequence; each dataset's config defines it."""
        raise NotImplementedError(f"{type(self).__name__} must define load_scene (use a dataset's config)")

    def sequence_key(self) -> str:
        """The name a protocol lists this sequence under (PandaSet folder, Waymo context)."""
        raise IDSplatError(f"--protocol {self.protocol}: this dataparser has no protocols; use idsplat-waymo or idsplat-pandaset")

    def resolved(self) -> "IDSplatDataParserConfig":
        """The config that loads: the protocol's settings applied (a copy; self is unchanged)."""
        if self.protocol is None:
            return self

        want = protocol_dataset(self.protocol)
        have = "waymo" if isinstance(self, WaymoDataParserConfig) else "pandaset"
        if want != have:
            raise IDSplatError(f"--protocol {self.protocol} is a {want} protocol, but the data is {have}; choose a {have} protocol")
        sel = select_protocol(self.protocol, self.sequence_key())
        CONSOLE.print(f"[bold]{sel.describe()}")
        return replace(
            self, protocol=None, cameras=sel.cameras, start_frame=sel.start_frame, end_frame=sel.end_frame,
            downscale_factor=sel.downscale_factor, train_fraction=sel.train_fraction, eval_every=sel.eval_every,
        )


@dataclass
class BuiltinDataParserConfig(IDSplatDataParserConfig):
    """The built-in synthetic street (PandaSet layout), generated on first use and cached."""

    subcommand: ClassVar[str] = DATAPARSER_SUBCOMMANDS["builtin"]

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    preset: str = "small"
    """Street preset: tiny, small, bench, varied or hard (docs/synthetic.md)."""
    seed: int = 0
    """Street seed (0-19 are the project's development streets)."""

    def load_scene(self) -> Scene:
        path = builtin_street(self.preset, self.seed)
        return load_sequence(
            path, cameras=self.cameras, start=self.start_frame, end=self.end_frame, load_lidar=self.load_lidar
        )


@dataclass
class PandaSetDataParserConfig(IDSplatDataParserConfig):
    """A PandaSet sequence folder (``.../pandaset/001``), or a street written by ``idsplat-synth``."""

    subcommand: ClassVar[str] = DATAPARSER_SUBCOMMANDS["pandaset"]

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    lidar_sensors: Tuple[int, ...] = bounded((0,), Range(0, 1, integer=True))
    """PandaSet lidars to use: 0 the spinning Pandar64, 1 the front PandarGT."""

    def load_scene(self) -> Scene:
        if self.data is None:
            raise IDSplatError("--data is required for idsplat-pandaset: a sequence folder (pandaset/001); idsplat-builtin needs none")
        return load_sequence(
            self.data, cameras=self.cameras, start=self.start_frame, end=self.end_frame,
            load_lidar=self.load_lidar, lidar_sensors=self.lidar_sensors,
        )

    def sequence_key(self) -> str:
        return Path(self.data).name if self.data is not None else ""


@dataclass
class WaymoDataParserConfig(IDSplatDataParserConfig):
    """A Waymo v1 segment (``segment-*.tfrecord``, or a folder of them with ``--segment``) or a v2
    root with ``--context-name``."""

    subcommand: ClassVar[str] = DATAPARSER_SUBCOMMANDS["waymo"]

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    segment: Optional[str] = None
    """v1 only, when --data is a folder of .tfrecord files: the segment (context name or file name)."""
    context_name: Optional[str] = None
    """v2 only: the segment context name inside the v2 root given as data (optional if the root has one)."""
    lidars: Optional[Tuple[str, ...]] = None
    """Lidars to load (TOP, FRONT, SIDE_LEFT, SIDE_RIGHT, REAR); default all five."""
    second_return: bool = True
    """Also keep second returns (extra rays where they hit)."""
    train_fraction: float = bounded(0.75, FRACTION)
    """Fraction of frames used for training when eval_every is None."""
    eval_every: Optional[int] = bounded(4, Range(2, integer=True))
    """Hold out every 4th frame: the paper's AD-GS / SplatFlow protocols on Waymo (75% train)."""

    def _detected(self):
        if self.data is None:
            raise IDSplatError("--data is required for idsplat-waymo: a segment-*.tfrecord file, a folder of them with --segment, or a v2 root")
        found = detect_data(self.data, self.segment, self.context_name)
        if found.format == "pandaset":
            raise IDSplatError(f"{self.data}: a PandaSet-layout folder, not Waymo data; use idsplat-pandaset (or plain --data)")
        return found

    def sequence_key(self) -> str:
        found = self._detected()
        if found.context_name is not None:
            return found.context_name

        return read_v1(found.path, None, [], 0, 1)[0].context_name  # a file not named segment-<context>

    def load_scene(self) -> Scene:
        found = self._detected()
        lidars = list(self.lidars) if self.lidars is not None else None
        estimate = estimate_segment_memory(
            found.path, found.context_name, lidars if self.load_lidar else [], self.second_return, self.start_frame, self.end_frame
        )
        available = available_memory_bytes()
        CONSOLE.print(f"waymo: {estimate.describe()}" + (f" ({available / 2**30:.1f} GiB available)" if available else ""))
        check_fits(estimate, available, str(found.path))
        kwargs = {"context_name": found.context_name} if found.format == "waymo-v2" else {}
        return load_segment(
            found.path, cameras=list(self.cameras) if self.cameras else None, start=self.start_frame,
            end=self.end_frame, load_lidar=self.load_lidar, lidars=lidars, second_return=self.second_return, **kwargs,
        )


@dataclass
class AutoDataParserConfig(IDSplatDataParserConfig):
    """Whatever ``--data`` holds, recognised by its layout (a PandaSet sequence folder, a Waymo v1
    ``.tfrecord`` or a folder of them with ``--segment``, a v2 root with ``--context-name``); without
    ``--data``, the built-in street."""

    subcommand: ClassVar[str] = DATAPARSER_SUBCOMMANDS["auto"]

    _target: Type = field(default_factory=lambda: IDSplatDataParser)
    segment: Optional[str] = None
    """Waymo v1 folder of segments: which one."""
    context_name: Optional[str] = None
    """Waymo v2 root: which context."""
    train_fraction: Optional[float] = bounded(None, FRACTION)  # type: ignore[assignment]
    """Fraction of frames used for training (default: the format's, 0.5 PandaSet, Waymo every 4th held out)."""
    eval_every: Optional[int] = bounded(None, Range(2, integer=True))
    """Hold out every k-th frame (overrides train_fraction)."""
    builtin_preset: str = "small"
    """Without --data: the built-in street's preset (tiny, small, bench)."""
    builtin_seed: int = 0
    """Without --data: the built-in street's seed."""
    lidars: Optional[Tuple[str, ...]] = None
    """Waymo: lidars to load (TOP, FRONT, SIDE_LEFT, SIDE_RIGHT, REAR); default all five."""
    second_return: bool = True
    """Waymo: also keep second returns (extra rays where they hit)."""
    lidar_sensors: Tuple[int, ...] = bounded((0,), Range(0, 1, integer=True))
    """PandaSet: lidars to use, 0 the spinning Pandar64, 1 the front PandarGT."""

    def concrete(self) -> IDSplatDataParserConfig:
        """The dataparser config of the recognised format, with these options."""
        shared = {name: getattr(self, name) for name in (
            "data", "cameras", "start_frame", "end_frame", "downscale_factor", "load_lidar", "protocol"
        )}
        if self.train_fraction is not None or self.eval_every is not None:
            shared.update(train_fraction=0.5 if self.train_fraction is None else self.train_fraction, eval_every=self.eval_every)
        waymo_options = [f for f, given in (("--lidars", self.lidars is not None), ("--second-return", not self.second_return)) if given]
        pandaset_options = ["--lidar-sensors"] if tuple(self.lidar_sensors) != (0,) else []
        if self.data is None:
            _refuse_options(waymo_options + pandaset_options, "the built-in street (no --data)")
            return BuiltinDataParserConfig(preset=self.builtin_preset, seed=self.builtin_seed, **shared)

        found = detect_data(self.data, self.segment, self.context_name)
        CONSOLE.print(f"[bold]data:[/bold] {found.describe()}")
        if found.format == "pandaset":
            _refuse_options(waymo_options, f"{self.data} (PandaSet layout; its lidars are chosen with --lidar-sensors)")
            return PandaSetDataParserConfig(lidar_sensors=tuple(self.lidar_sensors), **shared)
        _refuse_options(pandaset_options, f"{self.data} (Waymo; its lidars are chosen with --lidars)")
        shared["data"] = found.path if found.format == "waymo-v1" else self.data
        return WaymoDataParserConfig(
            context_name=found.context_name if found.format == "waymo-v2" else None, lidars=self.lidars,
            second_return=self.second_return, **shared,
        )

    def resolved(self) -> IDSplatDataParserConfig:
        return self.concrete().resolved()

    def load_scene(self) -> Scene:
        return self.resolved().load_scene()


def _refuse_options(options: list[str], data: str) -> None:
    """One-line error for a format's options given with data of another format."""
    if options:
        raise IDSplatError(f"{' and '.join(options)}: not an option for {data}; remove {'them' if len(options) > 1 else 'it'}")


class IDSplatDataParser(DataParser):
    """Scene -> nerfstudio ``DataparserOutputs``, with the split of the configured protocol."""

    config: IDSplatDataParserConfig
    includes_time = True

    def __init__(self, config: IDSplatDataParserConfig):
        super().__init__(config=config)
        self._scene: Optional[Scene] = None
        self._resolved: Optional[IDSplatDataParserConfig] = None

    @property
    def resolved(self) -> IDSplatDataParserConfig:
        """The config that loads (format recognised, protocol applied)."""
        if self._resolved is None:
            self._resolved = self.config.resolved()
        return self._resolved

    @property
    def scene(self) -> Scene:
        if self._scene is None:
            self._scene = self.resolved.load_scene()
            note_empty_sweeps(self._scene)
        return self._scene

    def _generate_dataparser_outputs(self, split: str = "train", **kwargs) -> DataparserOutputs:
        scene = self.scene
        config = self.resolved
        train_idx, eval_idx = split_frames(scene.num_frames, config.train_fraction, config.eval_every)
        frame_ids = set(scene.frame_indices[train_idx if split == "train" else eval_idx].tolist())
        # Pinhole rasterizers: distorted images (Waymo) are undistorted on load, keeping their K.
        images = [undistorted_view(im) for im in scene.images if im.frame_index in frame_ids]
        if not images:
            raise IDSplatError(f"no {split} images: check --cameras, the frame range and the split options")
        camera_names = scene.camera_names
        scale = 1.0 / config.downscale_factor
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
            metadata={SPLIT_KEY: SplitData(scene, images, scale, camera_names, split, self.config.protocol)},
        )


IDSplatDataParserUnion = tyro.conf.OmitSubcommandPrefixes[  # type: ignore[misc]
    tyro.extras.subcommand_type_from_defaults(
        {c.subcommand: c() for c in (AutoDataParserConfig, BuiltinDataParserConfig, PandaSetDataParserConfig,
                                     WaymoDataParserConfig)},
        prefix_names=False,
    )
]
"""The dataparsers as ``ns-train`` subcommands; ``idsplat-auto`` (the default) recognises ``--data``."""
