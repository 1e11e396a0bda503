"""Fast Point Feature Histograms (Rusu et al., 2009) from open3d: a geometry-only feature for lidar
without images. Normals and histograms are computed per observation (one instance at one frame)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from idsplat_ns._compat.libusb import import_open3d
from idsplat_ns.data.images import load_rgb
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.features.base import PointFeatureExtractor, PointFeatures, sample_colors
from idsplat_ns.instances.lifting import LiftedInstances
from idsplat_ns.ranges import AT_LEAST_ONE, POSITIVE, bounded


@dataclass(frozen=True)
class FpfhConfig:
    """Neighbourhoods of the normal and histogram estimates (metres)."""

    normal_radius: float = bounded(0.3, POSITIVE)
    """Radius of the neighbourhood used to estimate normals."""
    feature_radius: float = bounded(0.6, POSITIVE)
    """Radius of the neighbourhood of each histogram."""
    max_neighbours: int = bounded(50, AT_LEAST_ONE)
    """Cap on neighbours in either search."""


class FpfhFeatures(PointFeatureExtractor):
    """33-D FPFH descriptors (and colours where images exist)."""

    name = "fpfh"

    def __init__(self, config: FpfhConfig = FpfhConfig()):
        self.config = config
        self._o3d = None  # imported on first use (slow), so cached runs skip it

    def cache_key(self) -> dict:
        c = self.config
        return {"extractor": self.name, "normal_radius": c.normal_radius, "feature_radius": c.feature_radius, "nn": c.max_neighbours}

    def describe_points(self, points: np.ndarray) -> np.ndarray:  # points: [N, 3] -> [N, 33]
        if self._o3d is None:
            self._o3d = import_open3d()
        o3d, c = self._o3d, self.config
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=c.normal_radius, max_nn=c.max_neighbours))
        # Orient normals away from the object's centre so that histograms agree between frames.
        normals = np.asarray(cloud.normals)
        flip = np.sum(normals * (points - points.mean(0)), 1) < 0
        normals[flip] *= -1
        cloud.normals = o3d.utility.Vector3dVector(normals)
        fpfh = o3d.pipelines.registration.compute_fpfh_feature(
            cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=c.feature_radius, max_nn=2 * c.max_neighbours))
        return np.asarray(fpfh.data, dtype=np.float32).T

    def extract(self, scene: Scene, lifted: LiftedInstances, progress: bool = True) -> PointFeatures:
        feats, cols = {}, {}
        rgb_cache: dict[int, np.ndarray] = {}
        items = [(iid, o) for iid, obs in lifted.observations.items() for o in obs]
        for iid, o in tqdm(items, desc="fpfh features", disable=not progress):
            feats[(iid, o.frame)] = self.describe_points(o.points)
            if scene.images:
                c = np.zeros((len(o.points), 3), np.uint8)
                for img in np.unique(o.image_ids):
                    if int(img) not in rgb_cache:
                        rgb_cache = {int(img): load_rgb(scene.images[int(img)])}  # keep one decoded image
                    rows = o.image_ids == img
                    c[rows] = sample_colors(rgb_cache[int(img)], o.uv[rows])
                cols[(iid, o.frame)] = c
        return PointFeatures(self.name, feats, cols)
