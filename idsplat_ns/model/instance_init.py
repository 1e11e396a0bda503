"""Seed points of the instance-decomposed model: instance Gaussians, static Gaussians, random points.

Paper Sec. 3.5: dynamic Gaussians start from each instance's canonical point set, static ones from
the lidar points not associated with any instance; colours come from projecting the points into
the temporally closest image; random points are added within and beyond the lidar range. The
static part and the random points reuse :func:`initial_points_from_scene` (through its
``exclude`` argument); this module adds the instance points and the exclusion test.

Caps follow the scene: instance and static lidar points share ``InitConfig.max_lidar_points``
(instances take at most half of it, subsampled evenly across instances when they would exceed
it; the static points get the rest), and the random points scale with the static lidar points
as in :class:`InitConfig`. Only the frames of the given images (the training split) contribute
lidar points and colours.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.geometry import interpolate_poses
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks
from idsplat_ns.model.initialisation import (
    InitConfig,
    InitialPoints,
    color_points_from_images,
    initial_points_from_scene,
    knn_scales,
)
from idsplat_ns.model.trajectories import default_span_margin


@dataclass
class InstanceInitConfig:
    """How instance points are seeded and separated from the background."""

    box_margin: float = 0.3
    """Metres added on every side of an instance's canonical bounding box when removing its lidar
    points from the static set (the brief's 0.3 m: catches points on the box surface)."""
    span_margin: float | None = None
    """Seconds an instance is taken to exist beyond its first/last valid step (None: half the
    median step, as :class:`~idsplat_ns.model.trajectories.InstanceTrajectories`)."""
    max_instance_fraction: float = 0.5
    """At most this fraction of ``InitConfig.max_lidar_points`` goes to instance points."""
    max_color_frames: int = 8
    """Frames tried (nearest to the canonical frame first) when colouring an instance's points."""


@dataclass
class InstanceInitialPoints(InitialPoints):
    """Seed points with instance IDs: ID 0 points are in the world, ID k > 0 in instance k's
    canonical frame (``means`` mixes both frames, by ``instance_ids``)."""

    instance_ids: np.ndarray  # [N] int64


def instance_exclusion(
    tracks: InstanceTracks, box_margin: float = 0.3, span_margin: float | None = None
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A test ``(points [N, 3] world, times [N]) -> [N] bool``: the point lies, at its own time,
    inside some dynamic instance's canonical bounding box grown by ``box_margin``.

    The pose at a point's time comes from the instance's valid steps (interpolated, and
    extrapolated within ``span_margin`` of the span's ends); outside that window the instance does
    not exist and excludes nothing.
    """
    times_f = np.asarray(tracks.frame_times, dtype=np.float64)
    margin_t = default_span_margin(times_f) if span_margin is None else float(span_margin)
    boxes = []
    for inst in tracks.instances:
        good = np.flatnonzero(inst.valid)
        if len(good) == 0 or len(inst.canonical_points) == 0:
            continue
        lo = inst.canonical_points.min(0) - box_margin
        hi = inst.canonical_points.max(0) + box_margin
        step_t, step_T = times_f[good], inst.poses[good]
        t_lo, t_hi = step_t[0] - margin_t, step_t[-1] + margin_t
        # World AABB of the box over the whole window (cheap pre-filter before per-point poses).
        window = interpolate_poses(step_t, step_T, np.concatenate([[t_lo], step_t, [t_hi]]), extrapolate=True)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        world = np.einsum("kij,cj->kci", window[:, :3, :3], corners) + window[:, None, :3, 3]
        boxes.append((lo, hi, step_t, step_T, t_lo, t_hi, world.reshape(-1, 3).min(0), world.reshape(-1, 3).max(0)))

    def exclude(points: np.ndarray, times: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=np.float64)
        times = np.asarray(times, dtype=np.float64)
        out = np.zeros(len(points), bool)
        for lo, hi, step_t, step_T, t_lo, t_hi, w_lo, w_hi in boxes:
            cand = np.flatnonzero(
                (times >= t_lo) & (times <= t_hi) & np.all((points >= w_lo) & (points <= w_hi), axis=1) & ~out
            )
            if len(cand) == 0:
                continue
            T = interpolate_poses(step_t, step_T, times[cand], extrapolate=True)
            local = np.einsum("nji,nj->ni", T[:, :3, :3], points[cand] - T[:, :3, 3])  # R^T (p - t)
            out[cand[np.all((local >= lo) & (local <= hi), axis=1)]] = True
        return out

    return exclude


def _instance_colors(
    inst: InstanceTrack,
    points: np.ndarray,  # [P, 3] canonical
    tracks: InstanceTracks,
    images: list[CameraImage],
    load_image: Callable[[CameraImage], np.ndarray],
    max_frames: int,
) -> np.ndarray:  # [P, 3] in [0, 1]
    """Colours of canonical points from the images of the instance's frames nearest its canonical
    frame: at each frame the points are posed in the world with that frame's pose and projected
    into that frame's images only (another frame's image would see the object elsewhere)."""
    colors = np.full((len(points), 3), 0.5)
    found = np.zeros(len(points), bool)
    by_frame: dict[int, list[CameraImage]] = {}
    for im in images:
        by_frame.setdefault(im.frame_index, []).append(im)
    steps = [k for k in np.flatnonzero(inst.valid) if int(tracks.frame_indices[k]) in by_frame]
    steps.sort(key=lambda k: (abs(k - inst.canonical_frame), k))
    for k in steps[:max_frames]:
        todo = np.flatnonzero(~found)
        if len(todo) == 0:
            break
        T = inst.poses[k]
        world = points[todo] @ T[:3, :3].T + T[:3, 3]
        frame_images = by_frame[int(tracks.frame_indices[k])]
        c, ok = color_points_from_images(world, np.full(len(todo), tracks.frame_times[k]), frame_images, load_image)
        colors[todo[ok]] = c[ok]
        found[todo[ok]] = True
    return colors


def instance_initial_points(
    scene: Scene,
    tracks: InstanceTracks,
    config: InitConfig,
    load_image: Callable[[CameraImage], np.ndarray],
    images: list[CameraImage] | None = None,
    instance_config: InstanceInitConfig | None = None,
) -> InstanceInitialPoints:
    """Seed points for every dynamic instance of ``tracks`` (canonical frames) and for the
    background (world: lidar points outside all instances, plus random points).

    ``images`` is the training split: only its frames give lidar points and colours (None: all
    images). Instance colours are ``canonical_colors`` where the tracks have them, else projected
    from the images (see :func:`_instance_colors`). Scales are 20% (``config.scale_fraction``)
    of the 3-NN distance, computed among an instance's own points for instance points.
    """
    icfg = instance_config or InstanceInitConfig()
    rng = np.random.default_rng(config.seed)
    use_images = scene.images if images is None else images

    # Instance points, capped jointly (even fraction per instance keeps small objects).
    insts = [i for i in tracks.instances if len(i.canonical_points) > 0 and i.valid.any()]
    total = sum(len(i.canonical_points) for i in insts)
    cap = int(icfg.max_instance_fraction * config.max_lidar_points)
    keep_fraction = min(1.0, cap / total) if total else 1.0
    means, colors, scales, ids = [], [], [], []
    for inst in insts:
        pts = np.asarray(inst.canonical_points, dtype=np.float64)
        sel = np.arange(len(pts))
        if keep_fraction < 1.0:
            sel = np.sort(rng.choice(len(pts), max(1, int(keep_fraction * len(pts))), replace=False))
        pts = pts[sel]
        if inst.canonical_colors is not None:
            cols = np.asarray(inst.canonical_colors, dtype=np.float64)[sel] / 255.0
        else:
            cols = _instance_colors(inst, pts, tracks, use_images, load_image, icfg.max_color_frames)
        means.append(pts)
        colors.append(cols)
        scales.append(knn_scales(pts, config.scale_fraction))
        ids.append(np.full(len(pts), inst.instance_id, dtype=np.int64))
    num_instance_points = sum(len(m) for m in means)

    static_config = replace(config, max_lidar_points=max(1, config.max_lidar_points - num_instance_points))
    exclude = instance_exclusion(tracks, icfg.box_margin, icfg.span_margin)
    static = initial_points_from_scene(scene, static_config, load_image, images=images, exclude=exclude)

    return InstanceInitialPoints(
        means=np.concatenate([static.means] + means),
        colors=np.concatenate([static.colors] + colors),
        scales=np.concatenate([static.scales] + scales),
        is_lidar=np.concatenate([static.is_lidar, np.ones(num_instance_points, bool)]),
        instance_ids=np.concatenate([np.zeros(len(static.means), np.int64)] + ids),
    )
