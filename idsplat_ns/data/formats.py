"""What a ``--data`` path holds: a PandaSet sequence, a Waymo v1 segment (a file, or a folder of
them with a segment name) or a Waymo v2 root with a context name.

Detection looks only at names and folders, never at file contents, so it is instant and reads
nothing large; the parsers then check the contents and say what is wrong in one line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional

from idsplat_ns.errors import IDSplatError

DataFormat = Literal["pandaset", "waymo-v1", "waymo-v2"]
DATAPARSER_SUBCOMMANDS = {"auto": "idsplat-auto", "builtin": "idsplat-builtin", "pandaset": "idsplat-pandaset",
                          "waymo": "idsplat-waymo"}
"""The ns-train dataparser subcommand of each reader (``auto`` recognises ``--data``), written
once: the adapter registers them, the settings checks and idsplat-batch name them."""
V2_SPLITS = ("training", "validation", "testing")


@dataclass(frozen=True)
class DetectedData:
    """A recognised sequence on disk."""

    format: DataFormat
    """``pandaset``, ``waymo-v1`` or ``waymo-v2``."""
    path: Path
    """What the parser reads: the PandaSet sequence folder, the v1 ``.tfrecord`` file or the v2 root."""
    context_name: Optional[str] = None
    """Waymo context name (v1: from the file name where it has one; v2: the one asked for)."""

    def describe(self) -> str:
        """One line for the console: what was found."""
        if self.format == "pandaset":
            return f"{self.path}: a PandaSet-layout sequence (camera/, lidar/)"
        if self.format == "waymo-v1":
            return f"{self.path}: a Waymo v1 segment (TFRecord of Frame protos)"
        return f"{self.path}: a Waymo v2 root, context {self.context_name}"


def v1_context_name(path: Path) -> Optional[str]:
    """The context name in Waymo's v1 file name ``segment-<context>[_with_camera_labels].tfrecord``."""
    stem = path.name.removesuffix(".tfrecord")
    if not stem.startswith("segment-"):
        return None
    return stem.removeprefix("segment-").removesuffix("_with_camera_labels")


def _segment_file(folder: Path, segment: Optional[str]) -> Path:
    files = sorted(folder.glob("*.tfrecord"))
    if segment is None:
        if len(files) == 1:
            return files[0]
        names = ", ".join(v1_context_name(f) or f.name for f in files[:5]) + (", ..." if len(files) > 5 else "")
        raise IDSplatError(f"{folder}: {len(files)} Waymo v1 segments; choose one with --segment (one of {names})")
    want = segment.removeprefix("segment-").removesuffix(".tfrecord")
    hits = [f for f in files if v1_context_name(f) == want or f.stem == want or f.name == segment]
    if not hits:
        raise IDSplatError(f"{folder}: no segment {segment!r} here ({len(files)} .tfrecord files); check --segment")
    return hits[0]


def v2_contexts(root: Path) -> list[str]:
    """Context names with a ``vehicle_pose`` file under a v2 root (itself or its split folders)."""
    names: set[str] = set()
    for base in [root] + [root / s for s in V2_SPLITS]:
        names.update(p.stem for p in (base / "vehicle_pose").glob("*.parquet"))
    return sorted(names)


def is_v2_root(root: Path) -> bool:
    return any((base / "vehicle_pose").is_dir() for base in [root] + [root / s for s in V2_SPLITS])


def detect_data(path: Path, segment: Optional[str] = None, context_name: Optional[str] = None) -> DetectedData:
    """Recognise the format of ``path`` (see the module docstring); one-line error otherwise."""
    path = Path(path).expanduser()
    if not path.exists():
        raise IDSplatError(f"{path}: no such file or folder; pass --data to a PandaSet sequence, a Waymo v1 .tfrecord or a v2 root (a trained run reads it from data: in its config.yml: move the data back or edit that line)")
    if path.is_file():
        if path.suffix != ".tfrecord":
            raise IDSplatError(f"{path}: a file that is not a .tfrecord; pass a Waymo v1 segment file or a sequence folder")
        return DetectedData("waymo-v1", path, v1_context_name(path))
    if (path / "camera").is_dir() and (path / "lidar").is_dir():
        return DetectedData("pandaset", path)
    if is_v2_root(path):
        contexts = v2_contexts(path)
        if context_name is None:
            if len(contexts) != 1:
                shown = ", ".join(contexts[:3]) + (", ..." if len(contexts) > 3 else "")
                raise IDSplatError(f"{path}: a Waymo v2 root with {len(contexts)} contexts; choose one with --context-name ({shown})")
            context_name = contexts[0]
        elif context_name not in contexts:
            raise IDSplatError(f"{path}: context {context_name!r} is not in this v2 root (no vehicle_pose/{context_name}.parquet); check --context-name")
        return DetectedData("waymo-v2", path, context_name)
    if any(path.glob("*.tfrecord")):
        file = _segment_file(path, segment)
        return DetectedData("waymo-v1", file, v1_context_name(file))
    raise IDSplatError(
        f"{path}: not a recognised sequence (no camera/ and lidar/ folders, no .tfrecord files, no v2 vehicle_pose/ folder)"
    )
