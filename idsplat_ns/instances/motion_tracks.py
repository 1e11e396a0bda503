"""What lidar-motion detection works with: its settings (:class:`LidarMotionConfig`), one sweep's
object cluster (:class:`MotionCluster`) and a cluster track over sweeps (:class:`MotionTrack`).

Shared by the detector (lidar_motion.py), the free-space evidence (free_space.py) and the lifted
observations (lidar_motion_lifting.py); it imports none of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from idsplat_ns.data.tracks import class_from_size_speed
from idsplat_ns.ranges import ANY, AT_LEAST_ONE, POSITIVE, UNIT, bounded


@dataclass(frozen=True)
class LidarMotionConfig:
    """Settings of the lidar-motion instance source."""

    max_range: float = 80.0
    """Metres from the sensor: farther points are ignored (too sparse to cluster); the range
    instance lifting uses, so that a vehicle is found wherever it can be lifted."""
    ground_cell: float = bounded(0.5, POSITIVE)
    """Metres: side of the ground height cells."""
    ground_rank: int = 2
    """A cell's ground height is its ``ground_rank``-th lowest point (the lowest are noise)."""
    ground_neighbourhood: float = 0.0
    """Metres: a cell's ground height is at most the lowest cell's within this radius plus
    ``ground_neighbourhood_slack`` (a cell whose road the lidar never saw takes the body of the
    vehicles that drove over it for the ground; 0: off)."""
    ground_neighbourhood_slack: float = 0.15
    """Metres above the lowest neighbouring cell that a cell's ground may stand (slopes, kerbs)."""
    min_height: float = 0.3
    """Metres above the ground a point must be to belong to an object."""
    max_height: float = 4.0
    """Metres above the ground above which points are ignored (tree tops, bridges)."""
    cluster_eps: float = bounded(0.7, POSITIVE)
    """DBSCAN neighbourhood radius, metres."""
    cluster_min_samples: int = bounded(5, AT_LEAST_ONE)
    """DBSCAN core-point neighbour count."""
    cluster_voxel: float = 0.1
    """Metres: points are clustered as voxels of this side, weighted by their point counts
    (voxel_dbscan.py), so that a dense sweep costs what its surfaces cost; 0: every point."""
    min_points: int = 15
    """Clusters with fewer points are dropped."""
    max_extent: float = 22.0
    """Metres: clusters longer than this on the ground are structure, not a road user (a
    semi-truck is 16.5-20 m long; the built-in street's, 16.5 m, seen whole beside the ego, was
    dropped at 14 m)."""
    min_footprint: float = 0.4
    """Metres: clusters narrower than this on the ground in every direction are poles and posts
    (too thin for the free-space test: rays of other sweeps pass beside them), unless
    ``thin_max_height`` keeps them."""
    thin_max_height: float = 0.0
    """Metres: a cluster narrower than ``min_footprint`` is kept when its points span at most this
    height: a person seen from one side is 0.25-0.4 m across (on the `hard` development streets,
    thin clusters inside a person's box spanned 0.55-1.37 m in height, 5th-95th percentile, those
    outside, poles and posts, 1.94-3.53 m). 0: no thin cluster is kept."""
    person_track_footprint: float = 0.6
    """Metres: with ``thin_max_height``, a track whose median cluster is at most this wide on the
    ground is a person's, and keeps only its clusters that fit a person's footprint
    (``PEDESTRIAN_MAX_FOOTPRINT``): a walker beside a parked car or a bench joins their cluster
    for a sweep or two, and that view, its densest, set its class to car and its canonical centre
    2 m off the person (development street `hard` 1). People's tracks there had medians of
    0.38-0.50 m, cyclists' 0.83-1.55 m, vehicles' 1.36 m and more."""
    max_direction_error: float = 0.006
    """Radians: a ray of another sweep tests a point only when its direction is this close."""
    free_margin: float = 0.4
    """Metres: a ray ending farther than the point by this passed through it (free space)."""
    evidence_offsets_s: tuple[float, ...] = bounded((-1.0, -0.5, 0.5, 1.0), ANY)
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
    self_cover_radius: float = bounded(0.5, POSITIVE)
    """Metres: a point lies in the object's moved footprint when one of its own points, moved,
    is this close on the ground."""
    moving_score: float = bounded(0.6, UNIT)
    """A track whose median motion score exceeds this is moving."""
    min_displacement: float = 1.5
    """Metres: a moving track's centroid must travel at least this far over its life."""
    min_displacement_person: Optional[float] = 1.0
    """Metres: the same for a track whose class guess is ``pedestrian`` (a person walks 1.3 m a
    second: a track of a second or two travels less than a car's 1.5 m). None: ``min_displacement``
    for every track (docs/reports/2026-11-27-walking-pedestrians.md)."""
    merge_distance: float = 1.5
    """Metres: moving tracks whose clusters come this close in every shared sweep, at similar
    velocity, are parts of one object (a car seen in two pieces around an occluder) and merge."""
    merge_speed_difference: float = 3.0
    """m/s: largest difference of two tracks' mean velocities for them to be parts of one object."""
    merge_hand_over_sweeps: int = 2
    """Sweeps: a track that ends within this many sweeps of another's start, touching it (as
    ``merge_distance`` and ``merge_footprint`` say) in those shared sweeps and heading within 60
    degrees of it, hands over to it whatever their mean velocities (a car coming round a corner:
    the growing part the lidar sees slows its first piece's centroid). 0: no hand-over
    (docs/reports/2026-11-27-walking-pedestrians.md)."""
    hand_over_velocity_sweeps: int = 3
    """Ours: sweeps; a hand-over compares the headings of the two tracks where they meet, each from
    its centroids over this many sweeps at the junction (the last of one, the first of the other),
    not over each track's whole life: the two halves a turning car's track breaks into (the face
    the lidar sees changes) head apart over their lives, a U-turn's opposite ways, and alike where
    they meet. On 16 unseen streets: ID switches 17 -> 13 and fragmentations 7 -> 4, MOTA@2m up on
    `hard` 104-107 (0.778 -> 0.798) and `small` 100-103 (0.930 -> 0.939), unchanged on the other
    two presets (docs/reports/2026-11-29-close-pass-errors.md). 0: the whole lives."""
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

    def duration(self, clusters: Optional[slice] = None) -> float:
        """Seconds from the first cluster's mean ray time to the last's (of ``clusters``, a slice of
        them, where given)."""
        part = self.clusters if clusters is None else self.clusters[clusters]
        return float(np.mean(part[-1].times) - np.mean(part[0].times)) if part else 0.0

    def displacement(self) -> float:
        """Metres between the first and the last centroid on the ground."""
        return float(np.linalg.norm(self.clusters[-1].centroid[:2] - self.clusters[0].centroid[:2]))

    def mean_speed(self) -> float:
        """m/s of the centroid from its first to its last cluster (NaN for a single time)."""
        span = self.duration()
        return self.displacement() / span if span > 0 else float("nan")

    def mean_velocity(self, clusters: Optional[slice] = None) -> np.ndarray:  # -> [3] m/s
        """Centroid velocity from the first to the last cluster (of ``clusters``, a slice of them,
        where given; the last association's velocity for a single time)."""
        span = self.duration(clusters)
        if span <= 0:
            return self.velocity
        part = self.clusters if clusters is None else self.clusters[clusters]
        return (part[-1].centroid - part[0].centroid) / span

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
