"""Free-space evidence compensated for the object's own motion (instances/free_space.py): a bus
driving along its length reads mostly occupied in the plain score and free once its own moved
footprint is left out; a static face whose seen part drifts stays occupied; a track that is too
short to give a velocity keeps the plain score."""

from __future__ import annotations

import numpy as np
import pytest

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.instances.free_space import EvidenceSweeps, motion_compensated_scores, score_clusters
from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack

TIMES = np.arange(0.0, 3.01, 0.25)


def _sweep(t: float, face: tuple[float, float]) -> LidarSweep:
    """Rays from the origin over the half plane y > 0 (azimuth 10-170 degrees): a vertical face at
    y = 5 between ``face`` x bounds and 0.3-3 m up, else a far wall at y = 30."""
    az, el = np.meshgrid(np.radians(np.arange(10, 170, 0.25)), np.radians(np.arange(-5, 25, 0.5)))
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    hit = d * (5.0 / d[:, 1:2])
    on_face = (hit[:, 0] >= face[0]) & (hit[:, 0] <= face[1]) & (hit[:, 2] >= 0.3) & (hit[:, 2] <= 3.0)
    ranges = np.where(on_face, np.linalg.norm(hit, axis=1), 30.0 / d[:, 1])
    n = len(d)
    sweep = LidarSweep(frame_index=0, time=t, raw_timestamp=t, sensor_to_world=np.eye(4), origins=np.zeros((n, 3)),
                       directions=d, ranges=ranges, intensities=np.full(n, 0.5, np.float32), times=np.full(n, t),
                       returned=np.ones(n, bool), sensor_ids=np.zeros(n, np.int16))  # fmt: skip
    sweep.face = hit[on_face]
    return sweep


def _track(faces: list[tuple[float, float]], seen: list[tuple[float, float]] | None = None):
    """Sweeps of a face at each time and a track of its points (only those inside ``seen``, the part of
    the face the detector kept, where given)."""
    sweeps = [_sweep(t, f) for t, f in zip(TIMES, faces)]
    clusters = []
    for k, s in enumerate(sweeps):
        pts = s.face
        if seen is not None:
            pts = pts[(pts[:, 0] >= seen[k][0]) & (pts[:, 0] <= seen[k][1])]
        clusters.append(MotionCluster(k, pts, np.full(len(pts), TIMES[k])))
    return sweeps, MotionTrack(1, clusters)


def test_a_bus_driving_along_its_length_is_moving_once_its_own_footprint_is_left_out():
    config = LidarMotionConfig()
    sweeps, bus = _track([(-20.0 + 7.0 * t, -9.0 + 7.0 * t) for t in TIMES])  # 11 m long at 7 m/s
    evidence = EvidenceSweeps(sweeps)
    score_clusters([[c] for c in bus.clusters], evidence, config)
    motion_compensated_scores([bus], evidence, config)
    middle = bus.clusters[4:-4]  # evidence on both sides in time
    plain = np.median([c.score for c in middle])
    moved = np.median([c.moved_score for c in middle])
    assert plain < config.moving_score  # diluted: half a second later the bus still covers most of its old points
    assert moved > 0.9 and bus.motion_score() > config.moving_score


def test_a_static_face_whose_seen_part_drifts_stays_static():
    config = LidarMotionConfig()
    # A parked truck's side at x 8-16; the detector keeps a 4 m window that slides 1 m a second.
    sweeps, face = _track([(8.0, 16.0)] * len(TIMES), seen=[(9.0 + t, 13.0 + t) for t in TIMES])
    evidence = EvidenceSweeps(sweeps)
    score_clusters([[c] for c in face.clusters], evidence, config)
    motion_compensated_scores([face], evidence, config)
    assert np.nanmedian([c.score for c in face.clusters]) < 0.1
    assert face.motion_score() < 0.1  # the strip its drift leaves reads occupied


def test_no_velocity_no_compensated_score():
    config = LidarMotionConfig()
    sweeps, one = _track([(0.0, 4.0)])
    single = MotionTrack(1, one.clusters[:1])
    motion_compensated_scores([single], EvidenceSweeps(sweeps), config)
    assert np.isnan(single.clusters[0].moved_score)
    single.clusters[0].score = 0.3
    assert single.motion_score() == pytest.approx(0.3)  # falls back on the plain score
