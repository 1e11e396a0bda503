"""RGB colour as the point feature (the paper's ablation "RGB instead of image features")."""

from __future__ import annotations

import numpy as np

from idsplat_ns.instances.features.base import ImageFeatureExtractor, sample_colors


class RgbFeatures(ImageFeatureExtractor):
    """The pixel colour, centred on mid-grey so that cosine similarity separates dark from bright
    colours (raw RGB vectors are all in one octant and nearly parallel)."""

    name = "rgb"

    def cache_key(self) -> dict:
        return {"extractor": self.name, "version": 1}

    def describe(self, rgb: np.ndarray, uv: np.ndarray) -> np.ndarray:
        return sample_colors(rgb, uv).astype(np.float32) / 255.0 - 0.5
