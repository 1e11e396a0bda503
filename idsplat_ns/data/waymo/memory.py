"""How much memory loading a Waymo segment takes, known before loading it.

Rays are kept as float64 origins and directions plus range, intensity, time, flags (~73 bytes a
ray, ~100 at the peak of decoding; docs/data.md); images stay JPEG bytes. The
estimate counts the frames from the file's framing (v1, headers only) or the pose table (v2), so it
reads nothing large.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

from idsplat_ns.data.waymo import proto
from idsplat_ns.data.waymo.records import LASER_NAMES
from idsplat_ns.data.waymo.tfrecord import iter_record_refs, iter_records
from idsplat_ns.data.waymo.v2 import find_component_dir
from idsplat_ns.errors import IDSplatError

RANGE_IMAGE_SHAPES = {"TOP": (64, 2650), "FRONT": (200, 600), "SIDE_LEFT": (200, 600), "SIDE_RIGHT": (200, 600), "REAR": (200, 600)}
"""Beams x columns of each Waymo lidar's range image."""
# 73 bytes are kept per ray (float64 origins, directions, range, time; float32 intensity; flags and
# ids); decoding holds copies, so the measured peak is ~90-125 (bench/waymo_memory.py --by-lidars).
BYTES_PER_RAY = 100
SECOND_RETURN_SHARE = 0.05  # second returns are kept only where they hit: a few percent of the rays
JPEG_BYTES_PER_FRAME = 5 * 350_000  # five cameras, for v2 where record sizes are not at hand


@dataclass(frozen=True)
class SegmentMemory:
    """Estimated memory of one load."""

    frames: int
    """Frames that will be loaded."""
    lidars: tuple[str, ...]
    """Lidars that will be loaded."""
    rays_per_frame: int
    """First and (expected) second returns of those lidars, per frame."""
    bytes: int
    """Estimated bytes held by the loaded scene."""

    def describe(self) -> str:
        lidars = ", ".join(self.lidars) if self.lidars else "no lidar"
        return f"{self.frames} frames, {lidars}: about {self.bytes / 2**30:.1f} GiB in memory"


def available_memory_bytes() -> Optional[int]:
    """``MemAvailable`` of /proc/meminfo (Linux); None where it cannot be read."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def rays_per_frame(lidars: Sequence[str], second_return: bool) -> int:
    first = sum(RANGE_IMAGE_SHAPES[name][0] * RANGE_IMAGE_SHAPES[name][1] for name in lidars)
    return int(first * (1.0 + (SECOND_RETURN_SHARE if second_return else 0.0)))


def _v1_frames_and_bytes(path: Path, start: int, end: Optional[int]) -> tuple[int, int]:
    frames, size = 0, 0
    for ref in iter_record_refs(path):
        if ref.index >= start and (end is None or ref.index < end):
            frames, size = frames + 1, size + ref.length
    return frames, size


def _v2_frames(root: Path, context_name: str, start: int, end: Optional[int]) -> int:
    import pyarrow.parquet as pq

    total = pq.ParquetFile(find_component_dir(root, context_name) / "vehicle_pose" / f"{context_name}.parquet").metadata.num_rows
    return max(0, min(total, end if end is not None else total) - start)


def _lidars_in_v1(path: Path, start: int) -> set[str]:
    for _, data in iter_records(path, start, start + 1):
        frame = proto.Frame()
        frame.ParseFromString(data)
        return {LASER_NAMES.get(int(laser.name), "") for laser in frame.lasers}
    return set()


def _lidars_in_v2(root: Path, context_name: str) -> set[str]:
    import pyarrow.parquet as pq

    table = find_component_dir(root, context_name) / "lidar" / f"{context_name}.parquet"
    if not table.is_file():
        return set()
    names = pq.read_table(table, columns=["key.laser_name"]).column(0).unique().to_pylist()
    return {LASER_NAMES.get(int(n), "") for n in names}


def estimate_segment_memory(
    path: Path,
    context_name: Optional[str],
    lidars: Optional[Sequence[str]],
    second_return: bool,
    start: int = 0,
    end: Optional[int] = None,
) -> SegmentMemory:
    """Estimated memory of ``load_segment`` with these options (``lidars`` None: all five; [] none)."""
    names = tuple(LASER_NAMES.values()) if lidars is None else tuple(str(n).upper() for n in lidars)
    unknown = [n for n in names if n not in RANGE_IMAGE_SHAPES]
    if unknown:
        raise IDSplatError(f"--lidars {' '.join(unknown)}: not a Waymo lidar; choose from {' '.join(RANGE_IMAGE_SHAPES)}")
    if Path(path).is_dir():
        frames = _v2_frames(Path(path), context_name or "", start, end)
        image_bytes = frames * JPEG_BYTES_PER_FRAME
        held = _lidars_in_v2(Path(path), context_name or "") if names else set()
    else:
        frames, image_bytes = _v1_frames_and_bytes(Path(path), start, end)  # records hold the JPEGs
        held = _lidars_in_v1(Path(path), start) if names and frames else set()
    names = tuple(n for n in names if n in held)  # asked for and in the file
    rays = rays_per_frame(names, second_return)
    return SegmentMemory(frames, names, rays, int(frames * rays * BYTES_PER_RAY + image_bytes))


def check_fits(estimate: SegmentMemory, available: Optional[int], where: str) -> None:
    """One-line error when the load would not fit in the memory available now (90 %)."""
    if available is None or estimate.bytes <= 0.9 * available:
        return
    raise IDSplatError(
        f"{where}: {estimate.describe()}, but {available / 2**30:.1f} GiB are available; load fewer frames "
        "(--end-frame), fewer lidars (--lidars TOP), no second returns (--second-return False) or no lidar (--load-lidar False)"
    )
