"""Instances carried through the frames only the lidar saw (instances/out_of_view.py): a car
overtaking the ego, seen by the lidar from behind and by the cameras only once beside it, gets its
true poses over the frames before; a view that is not the car, a gap too long in time or the
frame limit ends the extension, and people are never carried; the lidar views are read whole
from the mask folder; and the whole registration stage poses such frames only when asked."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from _instances_fixtures import CAR_SIZE, body_features, box_surface, visible_from
from idsplat_ns.data.geometry import make_pose, rot_z, transform_points
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.lidar_motion_lifting import load_lidar_views
from idsplat_ns.instances.lifting import InstanceObservation, LiftedInstances
from idsplat_ns.instances.masks.lidar_motion import save_track_points
from idsplat_ns.instances.motion_tracks import MotionCluster, MotionTrack
from idsplat_ns.instances.out_of_view import extend_out_of_view, nearest_posed
from idsplat_ns.instances.registration import RegistrationConfig
from idsplat_ns.instances.tracks import InstanceTrack
from idsplat_ns.instances.trajectory_config import TrajectoryConfig
from idsplat_ns.instances.trajectory_estimation import estimate_trajectories

DT = 0.1
SENSORS = np.stack([np.array([1.2 * f, 0.0, 1.9]) for f in range(14)])  # the ego at 12 m/s


def _overtaking(num: int = 14):
    """True poses [F, 4, 4] of a car overtaking the ego on its left and gaining speed, and each
    frame's lidar view of it (the faces turned to the sensor, half the points)."""
    rng = np.random.default_rng(3)
    body = box_surface(6000, CAR_SIZE, rng)
    t = np.arange(num) * DT
    x = -14.0 + 13.0 * t + 6.0 * t**2  # from 14 m behind, faster than the ego
    poses = make_pose(rot_z(0.02 * t), np.stack([x, np.full(num, 3.5), np.full(num, CAR_SIZE[2] / 2)], 1))
    views = {}
    for f in range(num):
        world = transform_points(poses[f], body)
        keep = visible_from(world, poses[f], SENSORS[f]) & (rng.random(len(body)) < 0.5)
        views[f] = world[keep]
    return poses, views, body


def _track(poses: np.ndarray, body: np.ndarray, seen: list[int]) -> InstanceTrack:
    """The track registration leaves: posed (exactly) at the frames the cameras saw; its canonical
    frame is the car's own."""
    valid = np.zeros(len(poses), bool)
    valid[seen] = True
    filled = np.repeat(poses[seen[0]][None], len(poses), 0)
    filled[seen] = poses[seen]
    return InstanceTrack(7, "car", body, None, filled, valid, valid.astype(np.int64) * 500, valid.astype(float),
                         seen[0], point_frames=np.full(len(body), seen[0], np.int32))


def _errors(track: InstanceTrack, poses: np.ndarray, frames) -> np.ndarray:
    return np.array([np.linalg.norm(track.poses[f, :3, 3] - poses[f, :3, 3]) for f in frames])


def test_a_car_from_behind_is_posed_where_only_the_lidar_saw_it() -> None:
    poses, views, body = _overtaking()
    track = _track(poses, body, [10, 11, 12, 13])
    out = extend_out_of_view(track, views, np.arange(14) * DT, RegistrationConfig(), max_frames=20, sensors=SENSORS)
    assert out.valid.all()
    assert _errors(out, poses, range(10)).max() < 0.1
    assert out.point_counts[3] == len(views[3])  # what the lidar saw there
    assert np.array_equal(out.canonical_points, track.canonical_points)  # no colour: not canonical
    assert np.array_equal(out.poses[10:], track.poses[10:])


def test_the_extension_stops_at_a_view_that_is_not_the_car_and_at_the_limits() -> None:
    poses, views, body = _overtaking()
    times = np.arange(14) * DT
    track = _track(poses, body, [10, 11, 12, 13])
    other = dict(views)
    other[6] = np.random.default_rng(0).uniform(-20, 0, (400, 3))  # a cluster that is not the car
    out = extend_out_of_view(track, other, times, RegistrationConfig(), max_frames=20, sensors=SENSORS)
    assert np.flatnonzero(out.valid).tolist() == list(range(7, 14))
    limited = extend_out_of_view(track, views, times, RegistrationConfig(), max_frames=2, sensors=SENSORS)
    assert np.flatnonzero(limited.valid).tolist() == list(range(8, 14))
    gappy = np.concatenate([times[:9], times[9:] + 2.0])  # frame 8 two seconds before 9
    assert np.flatnonzero(extend_out_of_view(track, views, gappy, RegistrationConfig(), 20, max_gap=1.0).valid).tolist() == list(range(9, 14))
    assert extend_out_of_view(track, views, times, RegistrationConfig(), max_frames=0) is track
    walker = replace(track, label="pedestrian")  # a walker's cluster changes shape: never carried
    assert extend_out_of_view(walker, views, times, RegistrationConfig(), max_frames=20) is walker
    missing = {f: v for f, v in views.items() if f != 8}  # no lidar view: the extension ends there
    assert np.flatnonzero(extend_out_of_view(track, missing, times, RegistrationConfig(), 20).valid).tolist() == list(range(9, 14))


def test_nearest_posed_frames_in_time() -> None:
    valid = np.array([False, True, True, False, True])
    assert nearest_posed(valid, np.arange(5.0), 3, 2) == [2, 4]
    assert nearest_posed(valid, np.arange(5.0), 0, 5) == [1, 2, 4]


def test_lidar_views_read_whole_from_the_mask_folder(tmp_path) -> None:
    """Every cluster of an asked instance with enough returns, at its frame's position, whether a
    camera saw it or not; other instances and clusters too small are left out."""
    car = MotionTrack(4, [MotionCluster(0, np.arange(30.0).reshape(10, 3), np.zeros(10)),
                          MotionCluster(1, np.ones((2, 3)), np.zeros(2)),  # too few returns
                          MotionCluster(2, np.full((6, 3), 2.0), np.zeros(6))])
    other = MotionTrack(9, [MotionCluster(0, np.zeros((8, 3)), np.zeros(8))])
    save_track_points(tmp_path, [car, other], sweep_frame_indices=[10, 11, 12])
    scene = SimpleNamespace(frame_indices=np.array([10, 11, 12]))
    views = load_lidar_views(scene, tmp_path, [4], min_points=5)
    assert list(views) == [4] and sorted(views[4]) == [0, 2]
    assert np.array_equal(views[4][0], np.arange(30.0).reshape(10, 3))


def test_registration_carries_the_track_only_when_asked() -> None:
    """The whole stage: camera observations (with features) at frames 10-13 only, lidar views at
    every frame; with ``out_of_view_frames`` the frames before are posed, by default not."""
    poses, views, body = _overtaking()
    rng = np.random.default_rng(5)
    observations, features = [], {}
    for f in range(10, 14):
        local = body[rng.random(len(body)) < 0.4]
        observations.append(InstanceObservation(f, transform_points(poses[f], local), np.zeros(len(local), np.int32),
                                                np.zeros((len(local), 2), np.float32), seen_fraction=1.0))
        features[(7, f)] = body_features(local)
    scene = SimpleNamespace(num_frames=14, frame_times=np.arange(14) * DT, frame_indices=np.arange(14))
    lifted = LiftedInstances({7: "car"}, {7: observations})
    plain = estimate_trajectories(scene, lifted, PointFeatures("test", features, {}), TrajectoryConfig(), progress=False,
                                  lidar_views={7: views})
    assert np.flatnonzero(plain.instances[0].valid).tolist() == [10, 11, 12, 13]
    asked = estimate_trajectories(scene, lifted, PointFeatures("test", features, {}), TrajectoryConfig(out_of_view_frames=20),
                                  progress=False, lidar_views={7: views})
    (track,) = asked.instances
    assert track.valid.all()
    # Poses are canonical-to-world: compare the motion from frame 10, as pose errors are measured.
    moved = [track.poses[f] @ np.linalg.inv(track.poses[10]) @ poses[10] for f in range(10)]
    assert max(np.linalg.norm(m[:3, 3] - poses[f, :3, 3]) for f, m in enumerate(moved)) < 0.15
