"""The point-feature interface used to find correspondences for registration.

An extractor gives each lidar point of each observation a feature vector (cosine similarity is
taken between them). Image-based extractors (DINOv3, RGB, DAISY) sample an image descriptor at the
pixel where the point was painted; geometric ones (FPFH) describe the point's neighbourhood.
Alongside, every extractor returns the points' RGB colours where images exist (for initialising
the instance Gaussians).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
from tqdm import tqdm

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.images import load_rgb
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.cache import load_npz, save_npz
from idsplat_ns.instances.lifting import LiftedInstances

ObsKey = tuple[int, int]  # (instance ID, frame)


@dataclass
class PointFeatures:
    """Features (and colours) of every observation's points, aligned with its point rows."""

    extractor: str
    """Name of the extractor that ran (``dinov3``, ``rgb``, ``daisy``, ``fpfh``)."""
    features: dict[ObsKey, np.ndarray]
    """[N, D] float32 per (instance ID, frame)."""
    colors: dict[ObsKey, np.ndarray]
    """[N, 3] uint8 RGB per (instance ID, frame); empty when the scene has no images."""

    def of_instance(self, iid: int) -> "PointFeatures":
        """The features (and colours) of instance ``iid``'s observations only."""
        return PointFeatures(self.extractor, {k: v for k, v in self.features.items() if k[0] == iid},
                             {k: v for k, v in self.colors.items() if k[0] == iid})

    def save(self, path: Path) -> None:
        arrays = {}
        for (iid, f), v in self.features.items():
            arrays[f"f_{iid}_{f}"] = v
        for (iid, f), v in self.colors.items():
            arrays[f"c_{iid}_{f}"] = v
        save_npz(path, arrays, {"extractor": self.extractor}, compress=False)

    @classmethod
    def load(cls, path: Path) -> "PointFeatures":
        data, meta = load_npz(path)
        feats, cols = {}, {}
        for name, value in data.items():
            kind, iid, f = name.split("_")
            (feats if kind == "f" else cols)[(int(iid), int(f))] = value
        return cls(meta["extractor"], feats, cols)


def sample_bilinear(grid: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples of grid [h, w, C] at continuous positions xy [N, 2] (x, y in grid cells,
    cell centres at integers), clamped at the border. Returns [N, C] float32."""
    h, w = grid.shape[:2]
    x = np.clip(xy[:, 0], 0, w - 1)
    y = np.clip(xy[:, 1], 0, h - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, max(w - 2, 0))
    y0 = np.clip(np.floor(y).astype(np.int64), 0, max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    g = grid.astype(np.float32, copy=False)
    top = g[y0, x0] * (1 - ax) + g[y0, x1] * ax
    bottom = g[y1, x0] * (1 - ax) + g[y1, x1] * ax
    return (top * (1 - ay) + bottom * ay).astype(np.float32)


def sample_colors(rgb: np.ndarray, uv: np.ndarray) -> np.ndarray:  # rgb: [H, W, 3], uv: [N, 2]
    """[N, 3] uint8 colour at the pixel containing each uv."""
    col = np.clip(uv[:, 0].astype(np.int64), 0, rgb.shape[1] - 1)
    row = np.clip(uv[:, 1].astype(np.int64), 0, rgb.shape[0] - 1)
    return rgb[row, col]


def _image_scale(image: CameraImage, rgb: np.ndarray) -> np.ndarray:
    """uv (in intrinsics pixels) to pixels of the decoded image, in case their sizes differ."""
    return np.array([rgb.shape[1] / image.intrinsics.width, rgb.shape[0] / image.intrinsics.height], np.float32)


class PointFeatureExtractor(ABC):
    """Computes per-point features for every observation."""

    name: str = "base"

    @abstractmethod
    def cache_key(self) -> dict:
        """Settings (and model-file identity) the features depend on."""

    @abstractmethod
    def extract(self, scene: Scene, lifted: LiftedInstances, progress: bool = True) -> PointFeatures:
        """Features and colours of every observation's points."""


class ImageFeatureExtractor(PointFeatureExtractor):
    """Base of extractors that describe pixels: each image is decoded once and described at every
    pixel where a lidar point of some instance was painted."""

    @abstractmethod
    def describe(self, rgb: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Descriptors [N, D] of image rgb [H, W, 3] uint8 at pixel positions uv [N, 2]."""

    def extract(self, scene: Scene, lifted: LiftedInstances, progress: bool = True) -> PointFeatures:
        by_image: dict[int, list[tuple[ObsKey, np.ndarray]]] = defaultdict(list)
        sizes: dict[ObsKey, int] = {}
        for iid, obs_list in lifted.observations.items():
            for o in obs_list:
                sizes[(iid, o.frame)] = len(o.points)
                for img in np.unique(o.image_ids):
                    by_image[int(img)].append(((iid, o.frame), np.nonzero(o.image_ids == img)[0]))
        feats: dict[ObsKey, Optional[np.ndarray]] = {k: None for k in sizes}
        cols = {k: np.zeros((n, 3), np.uint8) for k, n in sizes.items()}
        for img_idx in tqdm(sorted(by_image), desc=f"{self.name} features", disable=not progress):
            image = scene.images[img_idx]
            rgb = load_rgb(image)
            entries = by_image[img_idx]
            uv = np.concatenate([lifted_uv(lifted, key, rows) for key, rows in entries]) * _image_scale(image, rgb)
            desc = self.describe(rgb, uv)
            colors = sample_colors(rgb, uv)
            start = 0
            for key, rows in entries:
                if feats[key] is None:
                    feats[key] = np.zeros((sizes[key], desc.shape[1]), np.float32)
                feats[key][rows] = desc[start : start + len(rows)]
                cols[key][rows] = colors[start : start + len(rows)]
                start += len(rows)
        return PointFeatures(self.name, {k: v for k, v in feats.items() if v is not None}, cols)


def lifted_uv(lifted: LiftedInstances, key: ObsKey, rows: np.ndarray) -> np.ndarray:
    """uv [len(rows), 2] of some points of one observation."""
    iid, frame = key
    obs = next(o for o in lifted.observations[iid] if o.frame == frame)
    return obs.uv[rows]
