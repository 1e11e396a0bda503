"""Lidar ray times in instance smoothing: a registration is placed at its rays' mean time, poses
are read at the frame times, and each point is re-posed at its own ray time (smoothing/instance_tracks.py).

The synthetic street's sweep fires the rays that hit a car up to 0.04 s after the frame time; at
12.5 m/s that put the registered car up to 0.32 m ahead and stretched its view by up to 0.33 m.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from idsplat_ns.data.geometry import invert_pose, transform_points
from idsplat_ns.instances.smoothing.instance_tracks import smooth_tracks
from idsplat_ns.instances.smoothing import SmoothingConfig, smooth_trajectory
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks

SPEED = 12.5  # m/s along world x


def _true_pose(t: float) -> np.ndarray:  # box frame -> world at time t
    T = np.eye(4)
    T[:3, 3] = [SPEED * t, 5.0, 0.8]
    return T


def _skewed_tracks(num_frames: int = 12, seed: int = 0) -> tuple[InstanceTracks, np.ndarray, list[np.ndarray]]:
    """One car observed at 10 Hz. Its rays are fired 0.03-0.005 s after the frame time (less at
    later frames) and sweep across the car in 0.03 s, front to back. The registered pose is the
    true pose at the rays' mean time (what an exact registration of the skewed view finds)."""
    rng = np.random.default_rng(seed)
    frame_times = 0.1 * np.arange(num_frames) + 0.007
    pts, frames, ray_times, bodies = [], [], [], []
    poses = np.zeros((num_frames, 4, 4))
    for f, tf in enumerate(frame_times):
        body = rng.uniform(-1, 1, (300, 3)) * [2.25, 0.9, 0.75]
        delay = 0.03 * (1 - f / num_frames) + 0.005
        t = tf + delay + 0.03 * (2.25 - body[:, 0]) / 4.5  # the scan reaches the rear last
        world = body + np.c_[SPEED * t, np.full(len(t), 5.0), np.full(len(t), 0.8)]  # _true_pose at each ray's time
        poses[f] = _true_pose(float(t.mean()))
        pts.append(transform_points(invert_pose(poses[f]), world))
        frames.append(np.full(len(body), f, np.int32))
        ray_times.append(t)
        bodies.append(body)
    inst = InstanceTrack(
        instance_id=1, label="car", canonical_points=np.concatenate(pts), canonical_colors=None,
        poses=poses, valid=np.ones(num_frames, bool), point_counts=np.full(num_frames, 300),
        fitness=np.ones(num_frames), canonical_frame=0, point_frames=np.concatenate(frames),
        point_times=np.concatenate(ray_times),
    )
    tracks = InstanceTracks(np.arange(num_frames), frame_times, [inst], [], {})
    return tracks, frame_times, bodies


def test_measurement_times_are_the_mean_ray_times_and_fall_back_to_frame_times():
    tracks, frame_times, _ = _skewed_tracks()
    inst = tracks.instances[0]
    expected = [inst.point_times[inst.point_frames == f].mean() for f in range(len(frame_times))]
    np.testing.assert_allclose(inst.measurement_times(frame_times), expected)
    assert np.array_equal(replace(inst, point_times=None).measurement_times(frame_times), frame_times)
    # Times that would not increase (a broken clock) give the frame times back.
    shuffled = inst.point_times.copy()
    shuffled[inst.point_frames == 3] += 1.0
    assert np.array_equal(replace(inst, point_times=shuffled).measurement_times(frame_times), frame_times)


def test_with_points_posed_by_keeps_world_positions():
    tracks, _, _ = _skewed_tracks()
    inst = tracks.instances[0]
    rng = np.random.default_rng(1)
    new = np.tile(np.eye(4), (len(inst.canonical_points), 1, 1))
    new[:, :3, 3] = rng.normal(size=(len(new), 3))
    moved = inst.with_points_posed_by(new)
    before = np.einsum("nij,nj->ni", inst.poses[inst.point_frames][:, :3, :3], inst.canonical_points) + inst.poses[inst.point_frames][:, :3, 3]
    after = np.einsum("nij,nj->ni", new[:, :3, :3], moved.canonical_points) + new[:, :3, 3]
    np.testing.assert_allclose(after, before, atol=1e-9)


def test_pose_at_margin_extrapolates_with_the_motion_model():
    times = 0.1 * np.arange(8)
    poses = np.stack([_true_pose(t) for t in times])
    sm = smooth_trajectory(times, poses, np.ones(8, bool))
    assert sm.pose_at(times[-1] + 0.03) is None
    for t in (times[0] - 0.03, times[-1] + 0.03):
        np.testing.assert_allclose(sm.pose_at(t, margin=0.05)[:3, 3], _true_pose(t)[:3, 3], atol=2e-3)


@pytest.mark.parametrize("use_ray_times", [True, False])
def test_smoothing_at_ray_times_removes_the_sweep_offset_and_deskews_points(use_ray_times):
    tracks, frame_times, bodies = _skewed_tracks()
    config = SmoothingConfig(measurement_times=use_ray_times, repose_points=use_ray_times)
    inst = smooth_tracks(tracks, config).instances[0]
    assert inst.valid.all()
    # Poses at the frame times, against the truth there (up to the constant canonical offset,
    # which is zero here: the canonical frame is the box frame).
    pose_error = np.array([np.linalg.norm(inst.poses[f, :3, 3] - _true_pose(t)[:3, 3]) for f, t in enumerate(frame_times)])
    # The car's points posed at a frame's time, against the car's true shape there.
    shape_error = np.concatenate([
        np.linalg.norm(transform_points(inst.poses[f], inst.canonical_points[inst.point_frames == f])
                       - transform_points(_true_pose(t), bodies[f]), axis=1)
        for f, t in enumerate(frame_times)
    ])
    if use_ray_times:
        assert pose_error.max() < 0.01
        assert shape_error.max() < 0.01
    else:  # the test can fail: at frame times the car is where the rays saw it, 0.1-0.4 m ahead
        assert pose_error.max() > 0.2
        assert shape_error.max() > 0.3
