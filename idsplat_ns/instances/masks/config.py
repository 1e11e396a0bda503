"""Choosing the mask source."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.masks.base import MaskSource
from idsplat_ns.instances.masks.grounded_sam2_onnx import GroundedSam2Config, GroundedSam2OnnxMasks
from idsplat_ns.instances.masks.gt_boxes import GtBoxMaskSource, GtBoxMasksConfig
from idsplat_ns.instances.masks.lidar_motion import LidarMotionMaskSource
from idsplat_ns.instances.masks.precomputed import PrecomputedMaskSource, PrecomputedMasksConfig
from idsplat_ns.instances.motion_tracks import LidarMotionConfig
from idsplat_ns.instances.options import cli_option

MaskKind = Literal["auto", "grounded_sam2", "precomputed", "lidar-motion", "ground-truth", "gt_boxes"]


@dataclass(frozen=True)
class MaskConfig:
    """Where instance masks come from."""

    kind: MaskKind = "auto"
    """``grounded_sam2`` (the paper's; needs the ONNX files), ``precomputed`` (a mask folder),
    ``lidar-motion`` (moving lidar clusters projected into the images: no model files, no
    annotations), ``ground-truth`` (the built-in street's own 2D masks: an ablation),
    ``gt_boxes`` (oracle: projected ground-truth boxes, for ablations only) or ``auto``:
    Grounded-SAM-2 when its detector file is given, else precomputed when a mask folder is given,
    else lidar-motion."""
    grounded_sam2: GroundedSam2Config = field(default_factory=GroundedSam2Config)
    """Grounded-SAM-2 model files and thresholds."""
    precomputed: PrecomputedMasksConfig = field(default_factory=PrecomputedMasksConfig)
    """The precomputed mask folder."""
    gt_boxes: GtBoxMasksConfig = field(default_factory=GtBoxMasksConfig)
    """Oracle settings."""
    lidar_motion: LidarMotionConfig = field(default_factory=LidarMotionConfig)
    """Settings of the lidar-motion source."""


def resolve_mask_kind(config: MaskConfig) -> str:
    """The source that will run (``auto`` resolved)."""
    if config.kind != "auto":
        return config.kind
    if config.grounded_sam2.detector_path is not None:
        return "grounded_sam2"
    if config.precomputed.mask_dir is not None:
        return "precomputed"
    return "lidar-motion"


def make_mask_source(kind: str, config: MaskConfig) -> MaskSource:
    """Build the source named ``kind`` (already resolved)."""
    if kind == "grounded_sam2":
        return GroundedSam2OnnxMasks(config.grounded_sam2)
    if kind == "precomputed":
        return PrecomputedMaskSource(config.precomputed)
    if kind == "gt_boxes":
        return GtBoxMaskSource(config.gt_boxes)
    if kind == "lidar-motion":
        return LidarMotionMaskSource(config.lidar_motion)
    if kind == "ground-truth":
        raise IDSplatError(f"{cli_option('masks.kind')} ground-truth: resolve it on the scene first (instances.modes.ground_truth_masks)")
    raise IDSplatError(f"{cli_option('masks.kind')} {kind!r} is unknown; use auto, grounded_sam2, precomputed, lidar-motion, ground-truth or gt_boxes")
