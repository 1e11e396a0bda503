"""The lidar-motion instance source: ground, free-space evidence, tracks on the built-in street, and
preprocessing that reads no ground truth at all."""

from __future__ import annotations

import dataclasses
import os
import shutil
import sys

import numpy as np
import pytest

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.instances.lidar_motion import (
    LidarMotionConfig,
    _SweepRays,
    ground_heights,
    merge_parts,
    MotionCluster,
    MotionTrack,
    moving_tracks,
    object_points,
)


def _sweep(points: np.ndarray, origin=(0.0, 0.0, 0.0), returned=None) -> LidarSweep:
    origin = np.asarray(origin, dtype=np.float64)
    offset = points - origin
    ranges = np.linalg.norm(offset, axis=1)
    pose = np.eye(4)
    pose[:3, 3] = origin
    n = len(points)
    return LidarSweep(frame_index=0, time=0.0, raw_timestamp=0.0, sensor_to_world=pose,
                      origins=np.tile(origin, (n, 1)), directions=offset / ranges[:, None], ranges=ranges,
                      intensities=np.full(n, 0.5, np.float32), times=np.zeros(n),
                      returned=np.ones(n, bool) if returned is None else returned, sensor_ids=np.zeros(n, np.int16))


def test_ground_is_the_low_rank_per_cell_and_objects_stand_above_it():
    rng = np.random.default_rng(0)
    road = np.c_[rng.uniform(-10, 10, (4000, 2)), rng.normal(-1.8, 0.01, 4000)]
    box = np.c_[rng.uniform(4, 6, (300, 1)), rng.uniform(-1, 1, (300, 1)), rng.uniform(-1.5, -0.3, (300, 1))]
    sweep = _sweep(np.concatenate([road, box]))
    config = LidarMotionConfig()
    keys, heights = ground_heights([sweep], config.ground_cell, config.ground_rank)
    assert np.median(heights) == pytest.approx(-1.8, abs=0.02)
    pts, _ = object_points(sweep, keys, heights, config)
    assert len(pts) > 200 and np.all(pts[:, 0] > 3.9) and np.all(pts[:, 2] > -1.8 + config.min_height)


def test_free_space_evidence_passing_ending_and_occluded_rays():
    # Another sweep's rays fan out from the origin to a wall at x = 20.
    az = np.radians(np.arange(-20, 20, 0.1))
    el = np.radians(np.arange(-5, 5, 0.1))
    A, E = np.meshgrid(az, el)
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    wall = d * (20.0 / d[:, :1])
    rays = _SweepRays(_sweep(wall))
    config = LidarMotionConfig()
    probe = np.array([[1.0, 0.05, 0.02], [1.0, -0.1, 0.03], [1.0, 0.2, -0.04]])
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    assert rays.evidence(probe * 10.0, config) == (3, 0)  # in front of the wall: the rays passed through
    assert rays.evidence(probe * (20.0 / probe[:, :1]), config) == (0, 3)  # on the wall: occupied
    assert rays.evidence(probe * 30.0, config) == (0, 0)  # behind it: occluded, no evidence
    no_return = _SweepRays(_sweep(wall, returned=np.zeros(len(wall), bool)))
    assert no_return.evidence(probe * 10.0, config) == (3, 0)  # nothing came back: free to the end


def test_parts_of_one_object_merge_and_neighbours_do_not():
    config = LidarMotionConfig()
    rng = np.random.default_rng(1)

    def track(track_id, y, x0=0.0, speed=1.0):
        clusters = [MotionCluster(k, np.c_[rng.uniform(0, 1.5, (40, 1)) + x0 + speed * k, rng.uniform(y, y + 1, (40, 1)),
                                            rng.uniform(0, 1, (40, 1))], np.full(40, 0.1 * k), 1.0) for k in range(5)]
        return MotionTrack(track_id, clusters, np.array([10.0 * speed, 0, 0]))

    front, rear = track(1, 0.0, x0=2.5), track(2, 0.0, x0=0.0)  # 1 m apart, same motion: one car
    beside = track(3, 3.5)  # the next lane: 2.5 m away
    oncoming = track(4, 0.0, x0=5.0, speed=-1.0)
    merged = merge_parts([front, rear, beside, oncoming], config)
    assert len(merged) == 3
    car = next(t for t in merged if len(t.clusters[0].points) == 80)
    assert all(len(c.points) == 80 for c in car.clusters)


@pytest.fixture(scope="module")
def street(tiny_street, tmp_path_factory):
    """A copy of the tiny street whose scene is loaded, then stripped of every ground-truth file."""
    from idsplat_ns.data.pandaset import load_sequence

    root = tmp_path_factory.mktemp("lm") / tiny_street.name
    shutil.copytree(tiny_street, root)
    scene = load_sequence(root)
    truth = [t for t in scene.tracks if t.moving]
    for folder in ("idsplat_extras", "annotations", "gt"):
        shutil.rmtree(root / folder, ignore_errors=True)
    return dataclasses.replace(scene, tracks=[], metadata={}), truth


def test_moving_tracks_are_the_moving_vehicles(street):
    scene, truth = street
    assert truth
    tracks = moving_tracks(scene, LidarMotionConfig())
    assert tracks
    for tr in tracks:  # each found track sits on a moving annotated object
        c = tr.clusters[len(tr.clusters) // 2]
        frame = scene.lidar[c.frame].frame_index
        centres = [t.pose_at_frame(frame)[:3, 3] for t in truth if t.pose_at_frame(frame) is not None]
        assert min(np.linalg.norm(x[:2] - c.centroid[:2]) for x in centres) < 3.0


_OPENED: list[str] = []
_RECORDING = [False]


def _record_open(event: str, args: tuple) -> None:
    if _RECORDING[0] and event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
        _OPENED.append(os.fsdecode(args[0]))


def test_self_supervised_preprocessing_reads_no_ground_truth(tiny_street, tmp_path):
    """With every ground-truth file on disk and the annotations loaded (moved 50 m aside), the
    default preprocessing opens none of those files (Python's audit hook sees every open()) and its
    instances follow the true moving vehicles, not the moved annotations."""
    from idsplat_ns.data.pandaset import load_sequence
    from idsplat_ns.instances.masks.config import MaskConfig
    from idsplat_ns.instances.runner import PreprocessConfig, run_preprocessing

    root = tmp_path / tiny_street.name
    shutil.copytree(tiny_street, root)
    scene = load_sequence(root)
    truth = [t for t in scene.tracks if t.moving]
    aside = np.eye(4)
    aside[1, 3] = 50.0
    moved = [dataclasses.replace(t, poses=aside @ t.poses) for t in scene.tracks]
    sys.addaudithook(_record_open)  # stays for the process; records only while the flag is set
    _OPENED.clear()
    _RECORDING[0] = True
    try:
        result = run_preprocessing(dataclasses.replace(scene, tracks=moved), PreprocessConfig(masks=MaskConfig()),
                                   tmp_path / "cache", progress=False, verbose=False)
    finally:
        _RECORDING[0] = False
    assert result.mask_source == "lidar-motion"
    ground_truth = [str(root / f) for f in ("idsplat_extras", "annotations", "gt")]
    assert (root / "annotations").is_dir()
    assert any(p.startswith(str(root)) for p in _OPENED), "the hook saw no read of the street"
    assert not [p for p in _OPENED if p.startswith(tuple(ground_truth))]
    assert 1 <= len(result.tracks.instances) <= len(truth) + 2
    for inst in result.tracks.instances:  # each found instance follows a true moving vehicle
        k = int(np.flatnonzero(inst.valid)[0])
        frame = int(result.tracks.frame_indices[k])
        centres = [t.pose_at_frame(frame)[:3, 3] for t in truth if t.pose_at_frame(frame) is not None]
        assert min(np.linalg.norm(c[:2] - inst.poses[k][:2, 3]) for c in centres) < 4.0
