"""Dense DAISY descriptors (Tola et al., 2010) from opencv-contrib: a weight-free image feature."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from idsplat_ns.instances.features.base import ImageFeatureExtractor
from idsplat_ns.ranges import AT_LEAST_ONE, POSITIVE, bounded


@dataclass(frozen=True)
class DaisyConfig:
    """Settings of ``cv2.xfeatures2d.DAISY_create``."""

    radius: float = bounded(15.0, POSITIVE)
    """Pixels from the centre to the outermost sampling ring."""
    rings: int = bounded(3, AT_LEAST_ONE)
    """Number of rings (``q_radius``)."""
    ring_histograms: int = bounded(8, AT_LEAST_ONE)
    """Histograms per ring (``q_theta``)."""
    orientations: int = bounded(8, AT_LEAST_ONE)
    """Gradient orientations per histogram (``q_hist``)."""


class DaisyFeatures(ImageFeatureExtractor):
    """DAISY descriptors of the grey image at each painted pixel (L2-normalised, 200-D by default)."""

    name = "daisy"

    def __init__(self, config: DaisyConfig = DaisyConfig()):
        self.config = config
        self._daisy = cv2.xfeatures2d.DAISY_create(
            radius=config.radius, q_radius=config.rings, q_theta=config.ring_histograms,
            q_hist=config.orientations, norm=cv2.xfeatures2d.DAISY_NRM_FULL,
        )

    def cache_key(self) -> dict:
        c = self.config
        return {"extractor": self.name, "radius": c.radius, "rings": c.rings, "hist": c.ring_histograms, "ori": c.orientations}

    def describe(self, rgb: np.ndarray, uv: np.ndarray) -> np.ndarray:
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        keypoints = [cv2.KeyPoint(float(x), float(y), 1.0) for x, y in uv]
        out, desc = self._daisy.compute(grey, keypoints)
        if desc is None or len(out) != len(uv):
            raise RuntimeError(f"DAISY returned {0 if desc is None else len(desc)} descriptors for {len(uv)} points")
        return desc.astype(np.float32)
