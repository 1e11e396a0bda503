"""Waymo Open Dataset parser: v1 TFRecord segments (no TensorFlow) and the v2 parquet layout.

Entry point: :func:`load_segment`. See ``docs/data.md`` for formats, conventions and measured
accuracy and memory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

from idsplat_ns.data.scene import Scene
from idsplat_ns.data.waymo.assemble import assemble_scene
from idsplat_ns.data.waymo.splits import ExperimentSetting, SegmentSpec, experiment_settings, load_split
from idsplat_ns.errors import IDSplatError


def load_segment(
    path: str | Path,
    cameras: Optional[Sequence[str]] = None,
    start: int = 0,
    end: Optional[int] = None,
    *,
    context_name: Optional[str] = None,
    lidars: Optional[Sequence[str]] = None,
    load_lidar: bool = True,
    second_return: bool = True,
    image_scale: float = 1.0,
    progress: bool = True,
) -> Scene:
    """Load frames ``start <= i < end`` of a Waymo segment as a :class:`Scene`.

    path: a v1 ``segment-*.tfrecord`` file, or a v2 root (``<root>/{training,validation}/<component>/``
        or a split folder holding the component folders) together with ``context_name``.
    cameras: Waymo camera names (``FRONT``, ``FRONT_LEFT``, ``FRONT_RIGHT``, ``SIDE_LEFT``,
        ``SIDE_RIGHT``, any case); None = all the segment has.
    start, end: frame range, ``end`` exclusive (None = to the last frame). Only these frames are
        read (v1 seeks over earlier records and stops at ``end``), so memory grows with the frames
        asked for, not the segment.
    lidars: lidar names (``TOP``, ``FRONT``, ``SIDE_LEFT``, ``SIDE_RIGHT``, ``REAR``); None = all.
    load_lidar: False skips range images entirely (camera-only scenes, much less memory).
    second_return: also keep second returns (as extra rays, only where they hit).
    image_scale: 1 keeps the JPEG bytes (``CameraImage.image_bytes``) at full resolution; another
        factor decodes and area-resamples them into ``CameraImage.image`` with matching intrinsics
        (0.5 gives the paper's 640x960 for the front cameras).
    progress: show a progress bar over frames (tqdm, on stderr).
    """
    if not 0.0 < image_scale <= 1.0:
        raise IDSplatError(f"image_scale={image_scale}: must be in (0, 1]")
    if start < 0 or (end is not None and end <= start):
        raise IDSplatError(f"start={start}, end={end}: need 0 <= start < end (end exclusive, None for the last frame)")
    path = Path(path)
    lidar_names = lidars if load_lidar else []
    # The readers are imported for the format at hand: importing this package (for its splits)
    # must not build the protobuf classes or load pyarrow.
    if path.is_dir():
        from idsplat_ns.data.waymo.v2 import read_v2

        calib, frames, source = read_v2(path, context_name, cameras, lidar_names, start, end, second_return)
        fmt = "v2"
    else:
        if not path.exists():
            raise IDSplatError(f"{path}: no such file or folder; pass a Waymo v1 .tfrecord or a v2 root with context_name=")
        from idsplat_ns.data.waymo.v1 import read_v1

        calib, frames = read_v1(path, cameras, lidar_names, start, end, second_return)
        source, fmt = path, "v1"
    if progress:
        from tqdm import tqdm

        frames = tqdm(frames, total=None if end is None else end - start, desc=f"waymo {calib.context_name}", unit="frame")
    from idsplat_ns.data.waymo.proto import SCHEMA_SOURCE

    return assemble_scene(
        calib, frames, source, image_scale=image_scale,
        metadata={"format": fmt, "protobuf_schema": SCHEMA_SOURCE if fmt == "v1" else None, "start": start, "end": end},
    )


__all__ = ["load_segment", "load_split", "experiment_settings", "SegmentSpec", "ExperimentSetting"]
