"""The paper's Waymo benchmark splits and evaluation settings, shipped as data files in ``splits/``.

``streetgs.json`` (8 sequences with start/end frames), ``notr_dynamic.json`` (32 whole segments),
``pvg.json`` (4 sequences with start/end frames) and ``experiment_settings.json`` (cameras,
resolution, train fraction and held-out frames per table). End frames are inclusive as printed in
the paper (-1 = last frame); :meth:`SegmentSpec.frame_range` gives ``load_segment``'s exclusive
``end``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Optional, Union

from idsplat_ns.errors import IDSplatError

SPLIT_NAMES = ("streetgs", "notr_dynamic", "pvg")


@dataclass(frozen=True)
class SegmentSpec:
    """One sequence of a benchmark split."""

    sequence_id: str
    """The benchmark's sequence number (e.g. StreetGS ``006``)."""
    segment: str
    """Waymo segment name, ``segment-<context>``."""
    start_frame: int
    """First frame (inclusive)."""
    end_frame: int
    """Last frame, inclusive as printed in the paper; -1 = the segment's last frame."""

    @property
    def context_name(self) -> str:
        """The Waymo context name (the segment name without ``segment-``)."""
        return self.segment.removeprefix("segment-")

    def frame_range(self, use_range: bool = True, max_frames: Optional[int] = None) -> tuple[int, Optional[int]]:
        """``(start, end)`` for :func:`load_segment` (end exclusive, None = to the last frame)."""
        start, end = (self.start_frame, None if self.end_frame < 0 else self.end_frame + 1) if use_range else (0, None)
        if max_frames is not None:
            end = start + max_frames if end is None else min(end, start + max_frames)
        return start, end

    def find_file(self, folder: Union[str, Path]) -> Path:
        """The v1 file of this segment in ``folder`` (``segment-<context>*.tfrecord``)."""
        hits = sorted(Path(folder).glob(f"{self.segment}*.tfrecord"))
        if not hits:
            raise IDSplatError(f"{folder}: no {self.segment}*.tfrecord; download segment {self.segment} of the Waymo Open Dataset v1")
        return hits[0]


@dataclass(frozen=True)
class ExperimentSetting:
    """How one of the paper's tables was evaluated."""

    name: str
    """Short name (``desiregs``, ``adgs``, ``coda``, ``splatflow``, ``lidar``, ``view_density``, ...)."""
    paper_table: str
    """Which table of the paper it reproduces."""
    split: str
    """Split file name (``notr_full`` is not shipped: the paper lists only the dynamic subset)."""
    num_sequences: int
    """Sequences in the setting."""
    cameras: tuple[str, ...]
    """Waymo camera names."""
    image_size: tuple[int, int]
    """Evaluation image size (height, width) of the front cameras."""
    train_fraction: Union[float, tuple[float, ...]]
    """Fraction of frames used for training (several for the view-density study)."""
    eval_every: Optional[int]
    """Every k-th frame is held out (None: linearly spaced by ``train_fraction``)."""
    max_frames: Optional[int]
    """Only the first frames of each sequence (None: all of the range)."""
    use_split_frame_range: bool
    """Whether the split's start/end frames apply (False: whole segments)."""
    notes: str
    """Protocol details from the paper's text."""

    @property
    def image_scale(self) -> float:
        """``load_segment``'s ``image_scale`` for this size (Waymo front cameras are 1280 x 1920)."""
        return self.image_size[0] / 1280.0


def _read_json(name: str) -> dict:
    try:
        text = resources.files("idsplat_ns.data.waymo").joinpath("splits", f"{name}.json").read_text()
    except FileNotFoundError:
        raise IDSplatError(f"split file {name}.json is missing from the installed package; reinstall idsplat_ns") from None
    return json.loads(text)


def load_split(name: str) -> list[SegmentSpec]:
    """The sequences of one split: ``streetgs``, ``notr_dynamic`` or ``pvg``."""
    if name not in SPLIT_NAMES:
        raise IDSplatError(f"split {name!r}: unknown; choose one of {', '.join(SPLIT_NAMES)}")
    return [SegmentSpec(**row) for row in _read_json(name)["sequences"]]


def experiment_settings() -> dict[str, ExperimentSetting]:
    """The paper's evaluation settings by name."""
    out = {}
    for row in _read_json("experiment_settings")["settings"]:
        tf = row["train_fraction"]
        out[row["name"]] = ExperimentSetting(
            name=row["name"], paper_table=row["paper_table"], split=row["split"], num_sequences=row["num_sequences"],
            cameras=tuple(row["cameras"]), image_size=tuple(row["image_size"]),
            train_fraction=tuple(tf) if isinstance(tf, list) else float(tf), eval_every=row["eval_every"],
            max_frames=row["max_frames"], use_split_frame_range=row["use_split_frame_range"], notes=row["notes"],
        )
    return out
