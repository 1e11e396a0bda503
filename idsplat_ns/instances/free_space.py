"""Free-space evidence of lidar clusters: did the object leave where it was?

A cluster point seen at time t is tested against other sweeps: the rays of that sweep nearest in
direction to the point either end near it (occupied then: static evidence), pass beyond it or
return nothing (free then: the object moved away), or end before it (occluded: no evidence).
A cluster's score is the share of free among free + occupied (:func:`score_clusters`).

A moving object covers part of its own old place at the other sweep's time: a bus driving along
its length half a second later still covers most of the points seen now, which then read as
occupied. :func:`motion_compensated_scores` counts only the points its moved footprint leaves,
with each cluster's velocity from its track.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack



class _SweepRays:
    """Direction lookup of one sweep's rays (a KD-tree on unit directions)."""

    def __init__(self, sweep: LidarSweep):
        self.origin = sweep.sensor_to_world[:3, 3]
        self.tree = cKDTree(sweep.directions)
        self.ranges = np.where(sweep.returned, sweep.ranges, np.inf)  # no return: free to the end

    def point_evidence(self, points: np.ndarray, config: LidarMotionConfig) -> tuple[np.ndarray, np.ndarray]:
        """Whether each of ``points`` [N, 3] is free [N] and occupied [N] as seen by this sweep.

        The few rays nearest in direction decide together: free only when every one passes beyond
        the point (a single grazing ray beside a thin pole must not call it free), occupied when
        any ends near it."""
        offset = points - self.origin
        dist = np.linalg.norm(offset, axis=1)
        # Threads: one query holds the points of every cluster tested against this sweep.
        gap, idx = self.tree.query(offset / dist[:, None], k=4, distance_upper_bound=config.max_direction_error,
                                   workers=-1)
        found = np.isfinite(gap)  # [N, 4]
        r = np.where(found, self.ranges[np.minimum(idx, len(self.ranges) - 1)], np.nan)
        d = dist[:, None]
        seen = found.any(1)
        beyond = np.where(found, r > d + config.free_margin, True).all(1) & seen
        near = (found & (np.abs(r - d) <= config.free_margin)).any(1)
        return beyond, near

    def evidence_of_sets(self, point_sets: list[np.ndarray], config: LidarMotionConfig) -> np.ndarray:
        """(free, occupied) counts [S, 2] of each of ``point_sets`` ([N_i, 3]) as seen by this
        sweep, in one query."""
        if not point_sets:
            return np.zeros((0, 2), np.int64)
        beyond, near = self.point_evidence(np.concatenate(point_sets), config)
        ends = np.cumsum([len(p) for p in point_sets])
        per_point = np.stack([beyond, near], axis=1).astype(np.int64)
        totals = np.concatenate([np.zeros((1, 2), np.int64), np.cumsum(per_point, axis=0)])
        return totals[ends] - totals[np.r_[0, ends[:-1]]]


class EvidenceSweeps:
    """Each sweep's ray lookup, made when first asked for and kept: the plain and the
    motion-compensated scores test against the same sweeps."""

    def __init__(self, sweeps: list[LidarSweep]):
        self.sweeps = sweeps
        self.times = np.array([s.time for s in sweeps])
        self._rays: dict[int, _SweepRays] = {}

    def rays(self, j: int) -> _SweepRays:
        if j not in self._rays:
            self._rays[j] = _SweepRays(self.sweeps[j])
        return self._rays[j]

    def around(self, k: int, offsets: tuple[float, ...]) -> set[int]:
        """The sweeps nearest to sweep ``k``'s time plus each offset, without ``k`` itself."""
        return {int(np.argmin(np.abs(self.times - (self.times[k] + dt)))) for dt in offsets} - {k}


def _free_share(free: int, occupied: int, config: LidarMotionConfig) -> float:
    """Free among free + occupied, NaN with less than ``config.min_evidence`` evidence."""
    return free / (free + occupied) if free + occupied >= config.min_evidence else float("nan")


def score_clusters(clusters_per_sweep: list[list[MotionCluster]], evidence: EvidenceSweeps, config: LidarMotionConfig) -> None:
    """Set each cluster's free-space motion score from the sweeps at the evidence offsets."""
    for k, clusters in enumerate(clusters_per_sweep):
        counts = np.zeros((len(clusters), 2), np.int64)  # free, occupied
        for j in evidence.around(k, config.evidence_offsets_s):
            counts += evidence.rays(j).evidence_of_sets([c.points for c in clusters], config)
        for cluster, (free, occupied) in zip(clusters, counts):
            cluster.score = _free_share(int(free), int(occupied), config)


def motion_compensated_scores(tracks: list[MotionTrack], evidence: EvidenceSweeps, config: LidarMotionConfig) -> None:
    """Set each tracked cluster's ``moved_score``: the free-space evidence of the points that the
    object does not cover itself at the evidence sweep's time, its points moved by the velocity of
    its track there (central differences of the clusters' centroids). A static object, velocity
    near 0, covers all its points: no evidence (NaN); one whose centroid drifts as the ego passes
    it leaves a strip that reads occupied."""
    times = evidence.times
    # Per evidence sweep, the points each scored cluster (by index) leaves there: one query of that sweep for all.
    left_at: dict[int, list[tuple[int, np.ndarray]]] = {}
    scored: list[MotionCluster] = []
    for track in tracks:
        if len(track.clusters) < 2:
            continue
        t = np.array([float(np.mean(c.times)) for c in track.clusters])
        if np.any(np.diff(t) <= 0):
            continue
        velocity = np.gradient(np.stack([c.centroid[:2] for c in track.clusters]), t, axis=0)  # [C, 2]
        for cluster, v in zip(track.clusters, velocity):
            scored.append(cluster)
            tree = cKDTree(cluster.points[:, :2])
            for j in evidence.around(cluster.frame, config.evidence_offsets_s):
                shift = v * (times[j] - times[cluster.frame])
                gap, _ = tree.query(cluster.points[:, :2] - shift, distance_upper_bound=config.self_cover_radius)
                left = cluster.points[~np.isfinite(gap)]
                if len(left):
                    left_at.setdefault(j, []).append((len(scored) - 1, left))
    counts = np.zeros((len(scored), 2), np.int64)  # free, occupied
    for j, pairs in left_at.items():
        index = [k for k, _ in pairs]
        np.add.at(counts, index, evidence.rays(j).evidence_of_sets([left for _, left in pairs], config))
    for cluster, (free, occupied) in zip(scored, counts):
        cluster.moved_score = _free_share(int(free), int(occupied), config)
