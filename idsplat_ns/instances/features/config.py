"""Choosing the point-feature extractor."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.features.base import PointFeatureExtractor
from idsplat_ns.instances.features.daisy import DaisyConfig, DaisyFeatures
from idsplat_ns.instances.features.dinov3_onnx import Dinov3Config, Dinov3OnnxFeatures
from idsplat_ns.instances.features.fpfh import FpfhConfig, FpfhFeatures
from idsplat_ns.instances.features.rgb import RgbFeatures
from idsplat_ns.instances.options import cli_option

FeatureKind = Literal["auto", "dinov3", "rgb", "daisy", "fpfh"]


@dataclass(frozen=True)
class FeatureConfig:
    """Which features give correspondences, and their settings."""

    kind: FeatureKind = "auto"
    """``dinov3`` (the paper's; needs ``dinov3.model_path``), ``rgb`` (ablation), ``daisy`` (weight-free
    image descriptor), ``fpfh`` (geometry only) or ``auto``: DINOv3 when a model file is given, else
    DAISY when the scene has images, else FPFH."""
    dinov3: Dinov3Config = field(default_factory=Dinov3Config)
    """DINOv3 ONNX settings."""
    daisy: DaisyConfig = field(default_factory=DaisyConfig)
    """DAISY settings."""
    fpfh: FpfhConfig = field(default_factory=FpfhConfig)
    """FPFH settings."""


def resolve_feature_kind(config: FeatureConfig, scene: Scene) -> str:
    """The extractor that will run (``auto`` resolved), with a printed note when falling back."""
    if config.kind != "auto":
        return config.kind
    if config.dinov3.model_path is not None:
        return "dinov3"
    if scene.images:
        print(f"note: no DINOv3 model given ({cli_option('features.dinov3.model-path')}); using DAISY descriptors for correspondences")
        return "daisy"
    print("note: no images and no DINOv3 model; using FPFH (geometry-only) descriptors for correspondences")
    return "fpfh"


def make_feature_extractor(kind: str, config: FeatureConfig) -> PointFeatureExtractor:
    """Build the extractor named ``kind`` (already resolved, not ``auto``)."""
    if kind == "dinov3":
        return Dinov3OnnxFeatures(config.dinov3)
    if kind == "rgb":
        return RgbFeatures()
    if kind == "daisy":
        return DaisyFeatures(config.daisy)
    if kind == "fpfh":
        return FpfhFeatures(config.fpfh)
    raise IDSplatError(f"{cli_option('features.kind')} {kind!r} is unknown; use auto, dinov3, rgb, daisy or fpfh")
