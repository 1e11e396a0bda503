"""Initial Gaussians from lidar: coloured lidar points plus random points inside and beyond range.

Following the paper's supplementary: lidar points (capped) are coloured by projecting them into
the temporally closest camera image; extra random points are added, half uniformly inside the
lidar range and half linearly in inverse distance (disparity) beyond it; every Gaussian starts at
opacity 0.5 with a scale of 20% of the mean distance to its three nearest neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
from scipy.spatial import cKDTree

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.scene import Scene


@dataclass
class InitConfig:
    """How the initial Gaussians are made."""

    max_lidar_points: int = 5_000_000
    """Cap on lidar points used (paper: 5M); the scene-size cap below usually binds first."""
    num_random_points: int = 2_000_000
    """Random points added (paper: 2M); half inside the lidar range, half beyond it."""
    points_per_lidar_point: Optional[float] = 0.5
    """Scale the random-point count with the scene: at most this many per kept lidar point
    (None: the fixed count above). Small scenes then do not drown in random points."""
    far_distance: float = 1000.0
    """Outer radius (metres) of the random points sampled beyond the lidar range."""
    initial_opacity: float = 0.5
    """Opacity of every initial Gaussian."""
    scale_fraction: float = 0.2
    """Initial scale as a fraction of the mean distance to the 3 nearest neighbours."""
    seed: int = 0
    """Random seed for subsampling and random points."""


@dataclass
class InitialPoints:
    """Seed points of the Gaussians (float64 world coordinates)."""

    means: np.ndarray  # [N, 3]
    colors: np.ndarray  # [N, 3] in [0, 1]
    scales: np.ndarray  # [N] isotropic scale (metres)
    is_lidar: np.ndarray  # [N] bool, False for random points


def color_points_from_images(
    points: np.ndarray,  # [N, 3] world
    point_times: np.ndarray,  # [N] seconds
    images: list[CameraImage],
    load: Callable[[CameraImage], np.ndarray],  # image -> [H, W, 3] uint8 at its intrinsics' size
) -> tuple[np.ndarray, np.ndarray]:
    """Colour each point from the temporally closest image that sees it.

    Images are tried in order of time distance (per point: the nearest frame first), so a point
    outside the closest camera's view falls back to the next camera. Returns colours [N, 3] in
    [0, 1] and a [N] bool of which points got one (the rest stay 0.5 grey).
    """
    colors = np.full((len(points), 3), 0.5)
    found = np.zeros(len(points), bool)
    if not images or len(points) == 0:
        return colors, found
    image_times = np.array([im.time for im in images])
    # Rank images by time distance for each point; process ranks in order so the closest wins.
    order = np.argsort(np.abs(point_times[:, None] - image_times[None, :]), axis=1)
    cache: dict[int, np.ndarray] = {}
    for rank in range(len(images)):
        todo = np.nonzero(~found)[0]
        if len(todo) == 0:
            break
        for k in np.unique(order[todo, rank]):
            sel = todo[order[todo, rank] == k]
            proj = images[k].project(points[sel])
            if not proj.valid.any():
                continue
            if k not in cache:
                cache[k] = load(images[k])
            pix = cache[k]
            h, w = pix.shape[:2]
            sx, sy = w / images[k].intrinsics.width, h / images[k].intrinsics.height
            hit = sel[proj.valid]
            uv = proj.uv[proj.valid]
            cols = np.clip((uv[:, 0] * sx).astype(int), 0, w - 1)
            rows = np.clip((uv[:, 1] * sy).astype(int), 0, h - 1)
            colors[hit] = pix[rows, cols] / 255.0
            found[hit] = True
    return colors, found


def random_points(
    num: int, centre: np.ndarray, lidar_range: float, far_distance: float, rng: np.random.Generator
) -> np.ndarray:
    """[num, 3] points: half uniform in the ball of ``lidar_range`` around ``centre``, half beyond it
    with distance linear in disparity (1/d uniform between 1/lidar_range and 1/far_distance)."""
    n_in = num // 2
    n_out = num - n_in
    d_in = rng.normal(size=(n_in, 3))
    d_in /= np.linalg.norm(d_in, axis=1, keepdims=True)
    r_in = lidar_range * rng.uniform(0, 1, n_in) ** (1 / 3)  # uniform in volume
    d_out = rng.normal(size=(n_out, 3))
    d_out /= np.linalg.norm(d_out, axis=1, keepdims=True)
    d_out[:, 2] = np.abs(d_out[:, 2])  # beyond range is sky and far facades: keep above ground
    disparity = rng.uniform(1 / far_distance, 1 / lidar_range, n_out)
    r_out = 1 / disparity
    return np.concatenate([centre + d_in * r_in[:, None], centre + d_out * r_out[:, None]])


def knn_scales(points: np.ndarray, fraction: float = 0.2, k: int = 3) -> np.ndarray:
    """[N] ``fraction`` of the mean distance of each point to its ``k`` nearest neighbours."""
    if len(points) <= k:
        return np.full(len(points), 0.1)
    dist, _ = cKDTree(points).query(points, k=k + 1)
    return fraction * np.maximum(dist[:, 1:].mean(1), 1e-4)


def initial_points_from_scene(
    scene: Scene,
    config: InitConfig,
    load_image: Callable[[CameraImage], np.ndarray],
    images: Optional[list[CameraImage]] = None,
    exclude: Optional[Callable[[np.ndarray, np.ndarray], np.ndarray]] = None,
) -> InitialPoints:
    """Seed points for the static scene (all lidar points, or those not excluded) plus random points.

    ``images`` restricts both the lidar sweeps and the colouring to the frames of those images
    (the training split: held-out frames contribute nothing); ``exclude`` maps (points [N, 3],
    times [N]) to a [N] bool of points to drop (e.g. those inside instances).
    """
    rng = np.random.default_rng(config.seed)
    frames = None if images is None else {im.frame_index for im in images}
    points, times = scene.all_lidar_points(max_points=config.max_lidar_points, seed=config.seed, frames=frames)
    if exclude is not None and len(points):
        keep = ~exclude(points, times)
        points, times = points[keep], times[keep]
    colors, _ = color_points_from_images(points, times, images if images is not None else scene.images, load_image)
    origins = scene.ego_poses[:, :3, 3]
    centre = origins.mean(0)
    if len(points):
        lidar_range = float(np.percentile(np.linalg.norm(points - centre, axis=1), 95))
    else:
        spread = np.linalg.norm(origins - centre, axis=1).max() if len(origins) else 0.0
        lidar_range = max(50.0, 2 * spread)
    num_random = config.num_random_points
    if config.points_per_lidar_point is not None and len(points):
        num_random = min(num_random, int(config.points_per_lidar_point * len(points)))
    rand = random_points(num_random, centre, lidar_range, max(config.far_distance, 2 * lidar_range), rng)
    means = np.concatenate([points, rand])
    all_colors = np.concatenate([colors, rng.uniform(0, 1, (len(rand), 3))])
    return InitialPoints(
        means=means,
        colors=all_colors,
        scales=knn_scales(means, config.scale_fraction),
        is_lidar=np.concatenate([np.ones(len(points), bool), np.zeros(len(rand), bool)]),
    )
