"""Moving objects found in the lidar alone: no model weights, no annotations (beyond the paper, for
users with no Grounded-SAM-2 files or no GPU).

1. **Ground**: each 0.5 m cell's height is a low rank of the points of all sweeps falling in it (the
   road is seen wherever a car has moved away); points more than ``min_height`` above it are kept.
2. **Clusters**: DBSCAN of each sweep's kept points, as 0.1 m voxels weighted by their point
   counts (voxel_dbscan.py); clusters of object size survive (with ``thin_max_height``, also a
   walker's, thinner than a pole but not as tall; a walker's track then keeps only its
   person-sized clusters).
3. **Free space** (free_space.py): a cluster point seen at time t is tested against sweeps
   ``evidence_offsets_s`` before and after: the ray of that sweep nearest in direction to the point
   either ends near it (occupied then: static evidence), passes beyond it or returns nothing (free
   then: the object has moved), or ends before it (occluded: no evidence). The cluster's motion
   score is the share of free among free + occupied; once clusters are tracks, only the points
   the object's own moved footprint leaves free count (a long vehicle covers most of its old
   points half a second later).
4. **Tracks**: clusters are associated over sweeps by their centroids (constant-velocity
   prediction, Hungarian assignment within a gate); a track is moving when its median motion score
   exceeds ``moving_score``. Parked cars, poles and walls fail the test. Moving tracks at similar
   mean velocity whose clusters touch, or together fit a car's footprint, in every shared sweep
   are pieces of one vehicle and merge. The class guess comes from footprint, height and speed
   (a tall vehicle seen end-on is a ``bus``, so that its centre is completed to a bus length).
5. **Masks**: each moving track's points, moved by its velocity to the image time, are projected
   into every camera and filled as their convex hull (nearer over farther), written in the mask
   folder format for the model; the tracks' own points are written beside them and become the
   lifted observations (lidar_motion_lifting.py), so that registration and smoothing take them
   unchanged.

The settings and the cluster and track types are in motion_tracks.py; the mask source that
writes step 5 is masks/lidar_motion.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from tqdm import tqdm

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import PEDESTRIAN_MAX_FOOTPRINT
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.free_space import EvidenceSweeps, motion_compensated_scores, score_clusters
from idsplat_ns.instances.ground import capped_by_neighbours, cell_heights, cell_keys
from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack
from idsplat_ns.instances.voxel_dbscan import voxel_dbscan


def ground_heights(sweeps: list[LidarSweep], cell: float, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """Sorted cell keys [C] and their ground heights [C] from all sweeps' returned points."""
    return cell_heights((s.points for s in sweeps), cell, rank)


def object_points(sweep: LidarSweep, ground_keys: np.ndarray, ground_z: np.ndarray, config: LidarMotionConfig):
    """World points [M, 3] and times [M] of a sweep that stand above the ground, within range."""
    ret = sweep.returned & (sweep.ranges <= config.max_range)
    pts, times = sweep.origins[ret] + sweep.directions[ret] * sweep.ranges[ret, None], sweep.times[ret]
    idx = np.clip(np.searchsorted(ground_keys, cell_keys(pts[:, :2], config.ground_cell)), 0, len(ground_keys) - 1)
    height = pts[:, 2] - ground_z[idx]
    keep = (height > config.min_height) & (height < config.max_height)
    return pts[keep], times[keep]


def cluster_sweep(points: np.ndarray, times: np.ndarray, frame: int, config: LidarMotionConfig) -> list[MotionCluster]:
    """Object-sized DBSCAN clusters of one sweep's above-ground points."""
    if len(points) < config.min_points:
        return []
    labels = voxel_dbscan(points, config.cluster_eps, config.cluster_min_samples, config.cluster_voxel)
    out = []
    for lab in np.unique(labels[labels >= 0]):
        sel = labels == lab
        extent = np.ptp(points[sel, :2], axis=0).max()
        # A walker seen from one side is as thin as a pole; its height tells them apart (thin_max_height).
        thin_person = (0 < config.thin_max_height and extent < config.min_footprint
                       and np.ptp(points[sel, 2]) <= config.thin_max_height)
        too_thin = extent < config.min_footprint and not thin_person
        if sel.sum() < config.min_points or extent > config.max_extent or too_thin:
            continue
        out.append(MotionCluster(frame, points[sel], times[sel]))
    return out


def associate(clusters_per_sweep: list[list[MotionCluster]], sweep_times: np.ndarray, config: LidarMotionConfig) -> list[MotionTrack]:
    """Tracks of clusters over sweeps: constant-velocity prediction and Hungarian assignment."""
    tracks: list[MotionTrack] = []
    active: list[MotionTrack] = []
    for k, clusters in enumerate(clusters_per_sweep):
        t = sweep_times[k]
        active = [tr for tr in active if k - tr.clusters[-1].frame <= config.max_missed_frames]
        matched: set[int] = set()
        if active and clusters:
            pred = np.stack([tr.clusters[-1].centroid + tr.velocity * (t - sweep_times[tr.clusters[-1].frame]) for tr in active])
            cent = np.stack([c.centroid for c in clusters])
            cost = np.linalg.norm(pred[:, None, :2] - cent[None, :, :2], axis=-1)
            rows, cols = linear_sum_assignment(np.where(cost <= config.association_gate, cost, 1e6))
            for r, c in zip(rows, cols):
                if cost[r, c] > config.association_gate:
                    continue
                tr, last = active[r], active[r].clusters[-1]
                dt = t - sweep_times[last.frame]
                if dt > 0:
                    tr.velocity = (clusters[c].centroid - last.centroid) / dt
                tr.clusters.append(clusters[c])
                matched.add(c)
        for c, cluster in enumerate(clusters):
            if c not in matched:
                track = MotionTrack(track_id=len(tracks) + 1, clusters=[cluster])
                tracks.append(track)
                active.append(track)
    return tracks


def motion_sweeps(scene: Scene) -> list[LidarSweep]:
    """The sweeps that a cluster's ``frame`` counts: those with rays."""
    return [s for s in scene.lidar if s.num_rays > 0]


def moving_tracks(scene: Scene, config: LidarMotionConfig, progress: bool = False) -> list[MotionTrack]:
    """The moving objects of ``scene``'s lidar, numbered 1..N in order of first appearance."""
    sweeps = motion_sweeps(scene)
    if not sweeps:
        raise IDSplatError(f"scene {scene.name}: no lidar sweeps; the lidar-motion instance source needs lidar")
    keys, heights = ground_heights(sweeps, config.ground_cell, config.ground_rank)
    heights = capped_by_neighbours(keys, heights, config.ground_cell, config.ground_neighbourhood,
                                   config.ground_neighbourhood_slack)
    clusters = []
    for k, sweep in enumerate(tqdm(sweeps, desc="lidar motion: clusters", unit="sweep", disable=not progress)):
        pts, times = object_points(sweep, keys, heights, config)
        clusters.append(cluster_sweep(pts, times, k, config))
    evidence = EvidenceSweeps(sweeps)
    score_clusters(clusters, evidence, config)
    tracks = associate(clusters, evidence.times, config)
    long_enough = [tr for tr in tracks if len(tr.clusters) >= config.min_track_frames]
    if config.compensate_own_motion:
        motion_compensated_scores([tr for tr in long_enough if tr.duration() >= config.compensate_min_seconds], evidence, config)
    score = (lambda tr: tr.motion_score()) if config.compensate_own_motion else (lambda tr: tr.median_score())
    moving = [tr for tr in long_enough if score(tr) > config.moving_score and tr.displacement() >= min_displacement(tr, config)]
    moving = merge_parts(moving, config)
    if config.thin_max_height > 0:  # after merging: the part a walker joined may have been a track of its own
        moving = [person_views(tr, config.person_track_footprint) for tr in moving]
    for n, tr in enumerate(moving, start=1):
        tr.track_id = n
    return moving


def person_views(track: MotionTrack, median_footprint: float) -> MotionTrack:
    """``track`` without its clusters wider than a person's footprint when its median cluster is
    at most ``median_footprint`` wide (a person's track: see ``LidarMotionConfig.person_track_footprint``)."""
    widths = np.array([np.ptp(c.points[:, :2], axis=0).max() for c in track.clusters])
    if len(widths) == 0 or np.median(widths) > median_footprint:
        return track
    fits = widths <= PEDESTRIAN_MAX_FOOTPRINT[0]
    return track if fits.all() else replace(track, clusters=[c for c, ok in zip(track.clusters, fits) if ok])


def min_displacement(track: MotionTrack, config: LidarMotionConfig) -> float:
    """Metres the track's centroid must travel to be moving: ``min_displacement_person`` for a
    track whose class guess is a pedestrian (where set), else ``min_displacement``."""
    if config.min_displacement_person is not None and track.label(config.long_vehicle_height) == "pedestrian":
        return config.min_displacement_person
    return config.min_displacement


def _parts_of_one_object(a: MotionTrack, b: MotionTrack, config: LidarMotionConfig) -> bool:
    frames_a = {c.frame: c for c in a.clusters}
    shared = [(frames_a[c.frame], c) for c in b.clusters if c.frame in frames_a]
    if not shared:
        return False
    # Velocities over each track's life: a car's pieces swap between tracks from sweep to sweep,
    # so centroid steps over a few shared sweeps jump by the piece offsets.
    va, vb = a.mean_velocity()[:2], b.mean_velocity()[:2]
    if np.linalg.norm(va - vb) > config.merge_speed_difference and not _hands_over(a, b, len(shared), va, vb, config):
        return False
    for ca, cb in shared:
        gap, _ = cKDTree(ca.points).query(cb.points, k=1)
        together = np.concatenate([ca.points, cb.points])
        if gap.min() > config.merge_distance and not fits_footprint(together, config.merge_footprint, va + vb):
            return False
    return True


def _hands_over(a: MotionTrack, b: MotionTrack, shared: int, va: np.ndarray, vb: np.ndarray,
                config: LidarMotionConfig) -> bool:
    """Whether one track ends in the sweeps where the other starts (at most ``merge_hand_over_sweeps``
    shared, the last of one and the first of the other) and both head the same way (within 60
    degrees; where they meet, with ``hand_over_velocity_sweeps``): one object's track handed over,
    not two objects side by side."""
    if not 0 < shared <= config.merge_hand_over_sweeps:
        return False
    first, second = (a, b) if a.clusters[0].frame <= b.clusters[0].frame else (b, a)
    if first.clusters[-1].frame > second.clusters[shared - 1].frame or second.clusters[-1].frame <= first.clusters[-1].frame:
        return False
    if config.hand_over_velocity_sweeps > 0:  # where they meet (see LidarMotionConfig.hand_over_velocity_sweeps)
        k = max(config.hand_over_velocity_sweeps, shared + 1)  # beyond the shared sweeps: a span of time
        va, vb = first.mean_velocity(slice(-k, None))[:2], second.mean_velocity(slice(0, k))[:2]
    speeds = float(np.linalg.norm(va) * np.linalg.norm(vb))
    return speeds > 0 and float(va @ vb) >= 0.5 * speeds


def fits_footprint(points: np.ndarray, size: tuple[float, float], heading: np.ndarray) -> bool:
    """Whether ``points`` [N, 3] fit a ground box of ``size`` (length, width) metres whose length
    runs along ``heading`` [2] (the direction of motion: vehicles are long along it, and two
    objects abreast are wide across it); along the points' principal axes for a zero heading."""
    xy = points[:, :2] - points[:, :2].mean(0)
    if len(xy) < 2:
        return True
    norm = float(np.linalg.norm(heading))
    if norm > 1e-6:
        along = heading / norm
        axes = np.stack([along, [-along[1], along[0]]])
    else:
        _, _, axes = np.linalg.svd(xy, full_matrices=False)
    extent = np.ptp(xy @ axes.T, axis=0)
    return bool(extent[0] <= max(size) and extent[1] <= min(size))


def merge_parts(tracks: list[MotionTrack], config: LidarMotionConfig) -> list[MotionTrack]:
    """Tracks that are parts of one object (see ``merge_distance``) merged, clusters of a sweep joined."""
    parent = list(range(len(tracks)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i in range(len(tracks)):
        for j in range(i + 1, len(tracks)):
            if root(i) != root(j) and _parts_of_one_object(tracks[i], tracks[j], config):
                parent[root(j)] = root(i)
    groups: dict[int, list[MotionTrack]] = {}
    for i, tr in enumerate(tracks):
        groups.setdefault(root(i), []).append(tr)
    merged = []
    for members in groups.values():
        by_frame: dict[int, list[MotionCluster]] = {}
        for tr in members:
            for c in tr.clusters:
                by_frame.setdefault(c.frame, []).append(c)
        clusters = [MotionCluster(f, np.concatenate([c.points for c in cs]), np.concatenate([c.times for c in cs]),
                                  _max_finite([c.score for c in cs]), _max_finite([c.moved_score for c in cs]))
                    for f, cs in sorted(by_frame.items())]
        longest = max(members, key=lambda t: len(t.clusters))
        merged.append(MotionTrack(longest.track_id, clusters, longest.velocity))
    return sorted(merged, key=lambda t: t.clusters[0].frame)


def _max_finite(values: list[float]) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return max(finite) if finite else float("nan")
