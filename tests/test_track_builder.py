"""The track builder's state and the declared list of passes: accept, drop, repose and coast keep
the poses, the accepted frames and the canonical chunks in agreement, and every pass beyond the
paper's is switched off by a setting that exists."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from idsplat_ns.data.geometry import invert_pose, make_pose, rot_z, transform_points
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.lifting import InstanceObservation
from idsplat_ns.instances.track_builder import TrackBuilder
from idsplat_ns.instances.trajectory_config import TrajectoryConfig
from idsplat_ns.instances.trajectory_passes import TRACK_PASSES, build_track


def _observations(num: int = 6, seed: int = 0) -> tuple[np.ndarray, list[InstanceObservation], np.ndarray]:
    rng = np.random.default_rng(seed)
    body = rng.uniform(-1, 1, (200, 3)) * [2.2, 0.9, 0.7]
    poses = np.stack([make_pose(rot_z(0.05 * k), np.array([3.0 * k, 1.0, 0.7])) for k in range(num)])
    obs = []
    for f in range(num):
        part = body[: 200 - 10 * abs(f - 2)]  # frame 2 the densest
        obs.append(InstanceObservation(f, transform_points(poses[f], part), np.zeros(len(part), np.int32),
                                       np.zeros((len(part), 2), np.float32), times=np.full(len(part), 0.1 * f)))
    return body, obs, poses


def test_start_places_the_canonical_frame_at_the_densest_views_box_centre() -> None:
    _, obs, _ = _observations()
    b = TrackBuilder.start(7, "car", obs, 6)
    ref = obs[2].points
    centre = 0.5 * (ref.min(0) + ref.max(0))
    assert b.reference_frame == 2 and b.frames == [2]
    np.testing.assert_allclose(b.poses[2][:3, 3], centre)
    np.testing.assert_allclose(b.points(), ref - centre)
    assert b.valid.tolist() == [False, False, True, False, False, False]
    assert [o.frame for o in b.pending()] == [0, 1, 3, 4, 5]


def test_accept_drop_repose_and_coast_keep_poses_frames_and_chunks_together() -> None:
    body, obs, poses = _observations()
    b = TrackBuilder.start(1, "car", obs, 6)
    canonical = invert_pose(b.poses[2])  # world -> canonical at the reference
    for f in (3, 1):
        b.accept(obs[f], poses[f] @ invert_pose(poses[2]) @ invert_pose(canonical))
    assert b.frames == [2, 3, 1] and b.valid[[1, 2, 3]].all()
    # every chunk is its frame's points mapped by its own pose: the same canonical body
    for chunk in b.chunks:
        np.testing.assert_allclose(transform_points(b.poses[chunk.frame], chunk.points), obs[chunk.frame].points, atol=1e-9)
    b.drop(3)
    assert b.frames == [2, 1] and not b.valid[3]
    turned = b.poses[1] @ make_pose(rot_z(0.3), np.zeros(3))
    b.repose(1, turned, 0.7)
    assert b.fitness[1] == 0.7
    np.testing.assert_allclose(transform_points(turned, b.chunks[1].points), obs[1].points, atol=1e-9)
    b.coast(5, poses[5])
    assert b.valid[5] and b.frames == [2, 1]  # a coasted frame brings no points
    track = b.track()
    assert track.canonical_frame == 2
    assert track.point_frames.tolist() == [2] * len(obs[2].points) + [1] * len(obs[1].points)
    np.testing.assert_allclose(track.point_times, np.concatenate([obs[2].times, obs[1].times]))
    assert track.point_counts.tolist() == [len(o.points) for o in obs]


def test_chunk_sensors_and_nearest_chunks() -> None:
    _, obs, poses = _observations()
    times = np.arange(6) * 0.25  # exact in binary: the tie between frames 2 and 4 is a tie
    sensors = np.stack([np.array([0.5 * f, -2.0, 1.8]) for f in range(6)])
    b = TrackBuilder.registered({o.frame: o for o in obs}, poses, times, sensor_positions=sensors)
    local = b.chunk_sensors([4, 0])
    expected = np.concatenate([np.repeat(transform_points(invert_pose(poses[f]), sensors[f][None]), len(obs[f].points), 0)
                               for f in (4, 0)])
    np.testing.assert_allclose(local, expected, atol=1e-9)
    assert b.nearest_chunks(3, 3) == [3, 2, 4]  # nearest first, ties in chunk order
    assert b.nearest_chunks(0, 5, max_gap=0.3) == [0, 1]


def test_features_are_read_by_the_mask_instance_they_were_computed_for() -> None:
    _, obs, _ = _observations()
    feats = {(4, o.frame): np.ones((len(o.points), 2)) * o.frame for o in obs}
    b = TrackBuilder.start(9, "car", obs, 6, PointFeatures("test", feats, {}), feature_id=4)
    assert b.features_of(3)[0, 0] == 3.0
    with pytest.raises(ValueError, match="no features for instance 4 at frame 7"):
        b.features_of(7)


def test_every_pass_beyond_the_papers_is_switched_off_by_a_setting_that_exists() -> None:
    names = [p.name for p in TRACK_PASSES]
    assert names == ["centroid", "registration", "chain", "heading-flips", "coast"]
    config = TrajectoryConfig()
    for p in TRACK_PASSES:
        if p.switch is None:
            continue
        assert p.runs_when(config, True), p.name  # on by default
        assert not p.runs_when(config, False), p.name  # every pass of ours needs the frame times
        path, value = p.switch
        *parents, leaf = path.split(".")
        owner = config
        for name in parents:
            owner = getattr(owner, name)
        assert hasattr(owner, leaf), path

        def set_path(c, names):
            if len(names) == 1:
                return replace(c, **{names[0]: value})
            return replace(c, **{names[0]: set_path(getattr(c, names[0]), names[1:])})

        assert not p.runs_when(set_path(config, path.split(".")), True), p.name


def test_centroid_ablation_translates_by_the_centroid_shift() -> None:
    _, obs, _ = _observations()
    b = build_track(TrackBuilder.start(1, "car", obs, 6), TrajectoryConfig(method="centroid"))
    assert b.valid.all() and (b.fitness == 1.0).all()
    shift = obs[4].points.mean(0) - obs[2].points.mean(0)
    np.testing.assert_allclose(b.poses[4][:3, 3] - b.poses[2][:3, 3], shift)
    np.testing.assert_allclose(b.poses[4][:3, :3], np.eye(3))


def test_people_take_their_own_method_through_the_whole_stage() -> None:
    """``people_method`` applies to pedestrians only (a car keeps ``method``), and through the whole
    registration stage a walker is placed by its points' centroids, with no rotation."""
    from types import SimpleNamespace

    from idsplat_ns.instances.lifting import LiftedInstances
    from idsplat_ns.instances.trajectory_config import config_for_label
    from idsplat_ns.instances.trajectory_estimation import estimate_trajectories

    config = TrajectoryConfig(people_method="centroid")
    assert config_for_label(config, "pedestrian").method == "centroid"
    assert config_for_label(config, "car").method == "registration"
    assert config_for_label(TrajectoryConfig(), "pedestrian").method == "registration"
    _, obs, _ = _observations()
    scene = SimpleNamespace(num_frames=6, frame_times=np.arange(6) * 0.1, frame_indices=np.arange(6))
    (walker,) = estimate_trajectories(scene, LiftedInstances({1: "pedestrian"}, {1: obs}), None, config,
                                      progress=False).instances
    assert walker.valid.all()
    shift = obs[4].points.mean(0) - obs[2].points.mean(0)
    np.testing.assert_allclose(walker.poses[4][:3, 3] - walker.poses[2][:3, 3], shift)
    np.testing.assert_allclose(walker.poses[4][:3, :3], np.eye(3))
