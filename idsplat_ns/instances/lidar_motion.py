"""Moving objects found in the lidar alone: no model weights, no annotations (beyond the paper, for
users with no Grounded-SAM-2 files or no GPU).

1. **Ground**: each 0.5 m cell's height is a low rank of the points of all sweeps falling in it (the
   road is seen wherever a car has moved away); points more than ``min_height`` above it are kept.
2. **Clusters**: DBSCAN (scikit-learn) of each sweep's kept points; clusters of object size survive.
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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from tqdm import tqdm

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import class_from_size_speed
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.free_space import EvidenceSweeps, motion_compensated_scores, score_clusters
from idsplat_ns.instances.lidar_motion_lifting import save_track_points
from idsplat_ns.instances.masks.base import InstanceMaskSet, MaskSource, mask_filename, write_instance_map, write_labels


@dataclass(frozen=True)
class LidarMotionConfig:
    """Settings of the lidar-motion instance source."""

    max_range: float = 80.0
    """Metres from the sensor: farther points are ignored (too sparse to cluster); the range
    instance lifting uses, so that a vehicle is found wherever it can be lifted."""
    ground_cell: float = 0.5
    """Metres: side of the ground height cells."""
    ground_rank: int = 2
    """A cell's ground height is its ``ground_rank``-th lowest point (the lowest are noise)."""
    min_height: float = 0.3
    """Metres above the ground a point must be to belong to an object."""
    max_height: float = 4.0
    """Metres above the ground above which points are ignored (tree tops, bridges)."""
    cluster_eps: float = 0.7
    """DBSCAN neighbourhood radius, metres."""
    cluster_min_samples: int = 5
    """DBSCAN core-point neighbour count."""
    min_points: int = 15
    """Clusters with fewer points are dropped."""
    max_extent: float = 22.0
    """Metres: clusters longer than this on the ground are structure, not a road user (a
    semi-truck is 16.5-20 m long; the built-in street's, 16.5 m, seen whole beside the ego, was
    dropped at 14 m)."""
    min_footprint: float = 0.4
    """Metres: clusters narrower than this on the ground in every direction are poles and posts
    (too thin for the free-space test: rays of other sweeps pass beside them)."""
    max_direction_error: float = 0.006
    """Radians: a ray of another sweep tests a point only when its direction is this close."""
    free_margin: float = 0.4
    """Metres: a ray ending farther than the point by this passed through it (free space)."""
    evidence_offsets_s: tuple[float, ...] = (-1.0, -0.5, 0.5, 1.0)
    """Seconds: sweeps at these offsets (the nearest to each) give free-space evidence."""
    min_evidence: int = 8
    """Points with evidence needed for a cluster's motion score to count."""
    compensate_own_motion: bool = True
    """Ours: decide motion by the free-space evidence of only the points that the object's own
    footprint, moved by its track's velocity, leaves at the evidence sweeps' times. A bus moving
    along its length still covers most of its old points half a second later (occupied evidence
    of a moving object): its plain score was 0.55, below ``moving_score``, and it was never an
    instance."""
    compensate_min_seconds: float = 1.0
    """Seconds a track must span for its velocity, and so its compensated score, to be trusted:
    static structure passed by the ego drifts in centroid (other faces come into view) for a few
    sweeps; compensated by that drift, its edge points read free."""
    self_cover_radius: float = 0.5
    """Metres: a point lies in the object's moved footprint when one of its own points, moved,
    is this close on the ground."""
    moving_score: float = 0.6
    """A track whose median motion score exceeds this is moving."""
    min_displacement: float = 1.5
    """Metres: a moving track's centroid must travel at least this far over its life."""
    merge_distance: float = 1.5
    """Metres: moving tracks whose clusters come this close in every shared sweep, at similar
    velocity, are parts of one object (a car seen in two pieces around an occluder) and merge."""
    merge_speed_difference: float = 3.0
    """m/s: largest difference of two tracks' mean velocities for them to be parts of one object."""
    merge_footprint: tuple[float, float] = (5.0, 2.5)
    """Metres (length, width): moving tracks whose clusters, in every shared sweep, together fit a
    box of this size on the ground (its length along their motion), at similar velocity, are parts of
    one vehicle too (a car followed from behind shows its rear face and its roof, split where the
    rear window returns nothing, often more than ``merge_distance`` apart)."""
    association_gate: float = 2.5
    """Metres: largest centroid distance to a track's prediction for an association."""
    max_missed_frames: int = 3
    """A track not associated for this many sweeps ends."""
    min_track_frames: int = 3
    """Moving tracks seen in fewer sweeps are dropped."""
    mask_dilation_px: int = 3
    """Pixels by which the projected hull is grown (lidar points sit inside the silhouette)."""
    lift_own_points: bool = True
    """Lift each track's own cluster points as its observations (lidar_motion_lifting.py, ours)
    instead of painting the lidar through its masks, where overlapping hulls hand a partly hidden
    car's points to the object in front of it."""
    long_vehicle_height: float = 2.2
    """Metres: a vehicle track whose clusters' median height extent exceeds this is labelled
    ``bus`` (buses and lorries seen end-on show a car-sized face; the label gives the amodal-centre
    stage a long-vehicle length, else the centre sits metres inside the rear)."""


@dataclass
class MotionCluster:
    """One cluster of one sweep."""

    frame: int
    """Index into the scene's sweeps."""
    points: np.ndarray
    """[N, 3] world points."""
    times: np.ndarray
    """[N] seconds, when each point's ray was fired."""
    score: float = float("nan")
    """Share of free-space evidence (NaN: too little evidence)."""
    moved_score: float = float("nan")
    """The same over only the points that the object itself does not cover at the evidence sweeps'
    times, moved by its track's velocity (free_space.motion_compensated_scores; NaN: too little)."""

    @property
    def centroid(self) -> np.ndarray:  # -> [3]
        return self.points.mean(0)


@dataclass
class MotionTrack:
    """Clusters associated over sweeps."""

    track_id: int
    clusters: list[MotionCluster] = field(default_factory=list)
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """[3] m/s, from the last associations."""

    def median_score(self) -> float:
        scores = [c.score for c in self.clusters if np.isfinite(c.score)]
        return float(np.median(scores)) if scores else float("nan")

    def motion_score(self) -> float:
        """The median motion-compensated score where clusters have one, else :meth:`median_score`."""
        scores = [c.moved_score for c in self.clusters if np.isfinite(c.moved_score)]
        return float(np.median(scores)) if scores else self.median_score()

    def duration(self) -> float:
        """Seconds from the first cluster's mean ray time to the last's."""
        return float(np.mean(self.clusters[-1].times) - np.mean(self.clusters[0].times)) if self.clusters else 0.0

    def displacement(self) -> float:
        """Metres between the first and the last centroid on the ground."""
        return float(np.linalg.norm(self.clusters[-1].centroid[:2] - self.clusters[0].centroid[:2]))

    def mean_speed(self) -> float:
        """m/s of the centroid from its first to its last cluster (NaN for a single time)."""
        span = self.duration()
        return self.displacement() / span if span > 0 else float("nan")

    def mean_velocity(self) -> np.ndarray:  # -> [3] m/s
        """Centroid velocity from the first to the last cluster (the last association's velocity
        for a single time)."""
        span = self.duration()
        if span <= 0:
            return self.velocity
        return (self.clusters[-1].centroid - self.clusters[0].centroid) / span

    def footprint(self) -> tuple[float, float]:
        """(length, width) metres on the ground along the principal axes of the cluster that holds
        the most points, grown to the 80th percentile of the lengths over the track's clusters
        (one view often shows a single face of the object)."""
        extents = []  # (points, [2] extent along the major and minor axis)
        for c in self.clusters:
            xy = c.points[:, :2] - c.points[:, :2].mean(0)
            if len(xy) < 3:
                continue
            _, _, axes = np.linalg.svd(xy, full_matrices=False)
            extents.append((len(xy), np.ptp(xy @ axes.T, axis=0)))
        if not extents:
            return float("nan"), float("nan")
        best = max(extents, key=lambda e: e[0])[1]
        length = max(float(best[0]), float(np.percentile([e[1][0] for e in extents], 80)))
        return length, float(best[1])

    def height(self) -> float:
        """Metres: median over the clusters of their vertical extent (NaN without clusters)."""
        return float(np.median([np.ptp(c.points[:, 2]) for c in self.clusters])) if self.clusters else float("nan")

    def label(self, long_vehicle_height: float = LidarMotionConfig.long_vehicle_height) -> str:
        """A class guess from the footprint, the height and the speed (the source has no detector
        label): ``pedestrian``, ``cyclist``, ``car``, (longer than 6.5 m) ``truck`` or (shorter
        but taller than ``long_vehicle_height``: a long vehicle seen end-on) ``bus``. People are
        never that tall: a person-sized footprint that is, is the end of a bus seen from afar (its
        front or back face, a bus length from the middle that the amodal centre gives a vehicle)."""
        length, width = self.footprint()
        cls = class_from_size_speed(length, width, self.mean_speed())
        if cls == "other":
            return "object"
        tall = self.height() > long_vehicle_height
        if cls != "vehicle" and not tall:  # a tall person-sized footprint goes on as a vehicle's end
            return cls
        if length > 6.5:
            return "truck"
        return "bus" if tall else "car"


def ground_heights(sweeps: list[LidarSweep], cell: float, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """Sorted cell keys [C] and their ground heights [C] from all sweeps' returned points."""
    pts = np.concatenate([s.points for s in sweeps])
    keys = _cell_keys(pts[:, :2], cell)
    order = np.lexsort((pts[:, 2], keys))
    keys, z = keys[order], pts[order, 2]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    counts = np.diff(np.r_[starts, len(keys)])
    pick = starts + np.minimum(rank, counts - 1)
    return keys[starts], z[pick]


def _cell_keys(xy: np.ndarray, cell: float) -> np.ndarray:  # xy: [N, 2] -> [N] int64
    ij = np.floor(xy / cell).astype(np.int64)
    return (ij[:, 0] << 32) + (ij[:, 1] & 0xFFFFFFFF)


def object_points(sweep: LidarSweep, ground_keys: np.ndarray, ground_z: np.ndarray, config: LidarMotionConfig):
    """World points [M, 3] and times [M] of a sweep that stand above the ground, within range."""
    ret = sweep.returned & (sweep.ranges <= config.max_range)
    pts, times = sweep.origins[ret] + sweep.directions[ret] * sweep.ranges[ret, None], sweep.times[ret]
    idx = np.clip(np.searchsorted(ground_keys, _cell_keys(pts[:, :2], config.ground_cell)), 0, len(ground_keys) - 1)
    height = pts[:, 2] - ground_z[idx]
    keep = (height > config.min_height) & (height < config.max_height)
    return pts[keep], times[keep]


def cluster_sweep(points: np.ndarray, times: np.ndarray, frame: int, config: LidarMotionConfig) -> list[MotionCluster]:
    """Object-sized DBSCAN clusters of one sweep's above-ground points."""
    from sklearn.cluster import DBSCAN

    if len(points) < config.min_points:
        return []
    labels = DBSCAN(eps=config.cluster_eps, min_samples=config.cluster_min_samples).fit_predict(points)
    out = []
    for lab in np.unique(labels[labels >= 0]):
        sel = labels == lab
        extent = np.ptp(points[sel, :2], axis=0).max()
        if sel.sum() < config.min_points or not config.min_footprint <= extent <= config.max_extent:
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
    moving = [tr for tr in long_enough if score(tr) > config.moving_score and tr.displacement() >= config.min_displacement]
    moving = merge_parts(moving, config)
    for n, tr in enumerate(moving, start=1):
        tr.track_id = n
    return moving


def _parts_of_one_object(a: MotionTrack, b: MotionTrack, config: LidarMotionConfig) -> bool:
    frames_a = {c.frame: c for c in a.clusters}
    shared = [(frames_a[c.frame], c) for c in b.clusters if c.frame in frames_a]
    if not shared:
        return False
    # Velocities over each track's life: a car's pieces swap between tracks from sweep to sweep,
    # so centroid steps over a few shared sweeps jump by the piece offsets.
    va, vb = a.mean_velocity()[:2], b.mean_velocity()[:2]
    if np.linalg.norm(va - vb) > config.merge_speed_difference:
        return False
    for ca, cb in shared:
        gap, _ = cKDTree(ca.points).query(cb.points, k=1)
        together = np.concatenate([ca.points, cb.points])
        if gap.min() > config.merge_distance and not fits_footprint(together, config.merge_footprint, va + vb):
            return False
    return True


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


def render_track_masks(scene: Scene, tracks: list[MotionTrack], config: LidarMotionConfig, out_dir: Path,
                       progress: bool = False) -> None:
    """Write one instance map per image: each track's points at the image time, hull-filled."""
    sweep_frames = [s.frame_index for s in motion_sweeps(scene)]
    by_frame: dict[int, list[tuple[MotionTrack, MotionCluster]]] = {}
    for tr in tracks:
        for c in tr.clusters:
            by_frame.setdefault(sweep_frames[c.frame], []).append((tr, c))
    kernel = np.ones((2 * config.mask_dilation_px + 1,) * 2, np.uint8) if config.mask_dilation_px > 0 else None
    for image in tqdm(scene.images, desc="lidar motion: masks", unit="image", disable=not progress):
        K = image.intrinsics
        ids = np.zeros((K.height, K.width), np.uint16)
        items = []
        for tr, c in by_frame.get(image.frame_index, []):
            pts = c.points + tr.velocity[None] * (image.time - c.times)[:, None]  # to the image time
            proj = image.project(pts)
            if proj.valid.sum() >= 3:
                items.append((float(np.median(proj.depth[proj.valid])), tr.track_id, proj.uv[proj.valid]))
        for _, track_id, uv in sorted(items, key=lambda x: -x[0]):  # far to near: near objects win
            hull = cv2.convexHull(np.round(uv).astype(np.int32))
            layer = np.zeros_like(ids, np.uint8)
            cv2.fillConvexPoly(layer, hull, 1)
            if kernel is not None:
                layer = cv2.dilate(layer, kernel)
            ids[layer > 0] = track_id
        write_instance_map(out_dir / mask_filename(image.camera, image.frame_index), ids)


def _finite_or_none(value: float):
    """JSON has no NaN: None where a value is unknown."""
    return round(float(value), 3) if np.isfinite(value) else None


class LidarMotionMaskSource(MaskSource):
    """Instance masks from moving lidar clusters (no model files, no annotations)."""

    name = "lidar-motion"

    def __init__(self, config: LidarMotionConfig):
        self.config = config

    def cache_key(self) -> dict:
        # labels: the version of the class-guess rule (cached instances.json files carry its
        # labels; 3: tall vehicles seen end-on are buses; 4: so are tall person-sized footprints).
        return {"kind": self.name, "labels": 4, **asdict(self.config)}

    def generate(self, scene: Scene, out_dir: Path, progress: bool = True) -> InstanceMaskSet:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        tracks = moving_tracks(scene, self.config, progress)
        render_track_masks(scene, tracks, self.config, out_dir, progress)
        save_track_points(out_dir, tracks, [s.frame_index for s in motion_sweeps(scene)])
        labels = {tr.track_id: tr.label(self.config.long_vehicle_height) for tr in tracks}
        write_labels(out_dir, labels, {tr.track_id: {"frames": len(tr.clusters), "motion_score": tr.median_score(),
                                                      "speed": _finite_or_none(tr.mean_speed()),
                                                      "footprint": [_finite_or_none(v) for v in tr.footprint()]}
                                 for tr in tracks})
        return InstanceMaskSet(out_dir, labels, self.name)

