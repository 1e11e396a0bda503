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
from idsplat_ns.data.tracks import class_from_size_speed
from idsplat_ns.instances.free_space import _SweepRays
from idsplat_ns.instances.lidar_motion import (cluster_sweep, fits_footprint, ground_heights, merge_parts, moving_tracks,
                                               object_points, person_views)
from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack


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


def test_cell_heights_capped_by_their_neighbours_match_a_brute_force_search():
    from idsplat_ns.instances.ground import _key_centres, capped_by_neighbours, cell_keys

    rng = np.random.default_rng(3)
    xy = rng.uniform(-6, 6, (400, 2))
    keys, first = np.unique(cell_keys(xy, 0.5), return_index=True)
    heights = rng.uniform(-2, 1, len(keys))
    capped = capped_by_neighbours(keys, heights, 0.5, 1.2, 0.15)
    centres = _key_centres(keys, 0.5)
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    reference = np.minimum(heights, np.where(dist <= 1.2 + 1e-9, heights[None], np.inf).min(1) + 0.15)
    assert np.array_equal(capped, reference)
    assert capped_by_neighbours(keys, heights, 0.5, 0.0, 0.15) is heights  # off


def test_a_car_over_road_the_lidar_never_saw_stands_above_the_ground_its_neighbours_give():
    # The road is seen beside the lane, never under it (far away the lines pass over it): without
    # the cap the car's own lowest points are the ground of its cells and most of it vanishes.
    rng = np.random.default_rng(1)
    road = np.c_[rng.uniform(40, 60, (3000, 1)), rng.uniform(1.5, 5, (3000, 1)), rng.normal(-1.9, 0.01, (3000, 1))]
    car = np.c_[rng.uniform(48, 52.5, (400, 1)), rng.uniform(-0.2, 1.0, (400, 1)), rng.uniform(-1.5, -0.4, (400, 1))]
    sweep = _sweep(np.concatenate([road, car]))
    plain = LidarMotionConfig()
    capped = dataclasses.replace(plain, ground_neighbourhood=2.0)
    keys, heights = ground_heights([sweep], plain.ground_cell, plain.ground_rank)
    from idsplat_ns.instances.ground import capped_by_neighbours

    lifted = capped_by_neighbours(keys, heights, capped.ground_cell, capped.ground_neighbourhood,
                                  capped.ground_neighbourhood_slack)
    without, _ = object_points(sweep, keys, heights, plain)
    with_cap, _ = object_points(sweep, keys, lifted, capped)
    car_without, car_with = without[without[:, 1] < 1.2], with_cap[with_cap[:, 1] < 1.2]
    assert len(car_with) > 0.95 * len(car) and len(car_without) < 0.7 * len(car)
    assert len(with_cap) - len(car_with) == len(without) - len(car_without) == 0  # the road stays ground


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
    assert rays.evidence_of_sets([probe * 10.0], config)[0].tolist() == [3, 0]  # in front of the wall: the rays passed through
    assert rays.evidence_of_sets([probe * (20.0 / probe[:, :1])], config)[0].tolist() == [0, 3]  # on the wall: occupied
    assert rays.evidence_of_sets([probe * 30.0], config)[0].tolist() == [0, 0]  # behind it: occluded, no evidence
    no_return = _SweepRays(_sweep(wall, returned=np.zeros(len(wall), bool)))
    assert no_return.evidence_of_sets([probe * 10.0], config)[0].tolist() == [3, 0]  # nothing came back: free to the end


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


def _box_track(track_id: int, size, centre, velocity, frames: int = 5, seed: int = 0, dt: float = 0.2) -> MotionTrack:
    """A track whose clusters are points on a box's surface region moving at ``velocity``."""
    rng = np.random.default_rng(seed)
    velocity = np.asarray(velocity, float)
    clusters = []
    for k in range(frames):
        pts = np.asarray(centre) + rng.uniform(-0.5, 0.5, (60, 3)) * np.asarray(size) + velocity * dt * k
        clusters.append(MotionCluster(k, pts, np.full(60, dt * k), 1.0))
    return MotionTrack(track_id, clusters, velocity)


def test_a_tall_vehicle_seen_end_on_is_a_bus_and_a_car_face_is_a_car():
    # Points of the rear face of a 3.1 m bus (a 2.5 m wide, 2.8 m tall wall above min_height) and
    # of the rear face of a car (1.8 m wide, 1.2 m tall), both driving away at 7 m/s.
    bus = _box_track(1, (0.1, 2.5, 2.8), (20.0, 0.0, 1.7), (7.0, 0.0, 0.0))
    car = _box_track(2, (0.1, 1.8, 1.2), (20.0, 0.0, 0.9), (7.0, 0.0, 0.0))
    assert bus.height() == pytest.approx(2.8, abs=0.15)
    assert (bus.label(), car.label()) == ("bus", "car")
    assert bus.label(long_vehicle_height=3.0) == "car"  # the threshold decides


def test_a_tall_person_sized_footprint_is_the_end_of_a_bus():
    # A bus's front seen from 60 m: the 2.5 m face and 0.5 m of its rounded corners, 2.8 m tall. Its
    # footprint alone is a cyclist's (length <= 2.7 m, width 0.25-0.9 m); no cyclist is that tall.
    bus_end = _box_track(1, (0.5, 2.5, 2.8), (60.0, 0.0, 1.7), (-9.0, 0.0, 0.0))
    cyclist = _box_track(2, (1.8, 0.6, 1.5), (15.0, 3.0, 0.9), (5.0, 0.0, 0.0))
    walker = _box_track(3, (0.6, 0.6, 1.5), (10.0, 6.0, 0.9), (0.0, 1.2, 0.0))
    assert class_from_size_speed(*bus_end.footprint(), bus_end.mean_speed()) == "cyclist"  # what the size says
    assert (bus_end.label(), cyclist.label(), walker.label()) == ("bus", "cyclist", "pedestrian")
    assert bus_end.label(long_vehicle_height=3.0) == "cyclist"  # the same threshold as end-on vehicles


def test_objects_are_kept_out_to_the_lifting_range():
    # A box 75 m away on flat ground: within the default range (the 80 m of instance lifting).
    rng = np.random.default_rng(2)
    road = np.c_[rng.uniform(70, 80, (8000, 1)), rng.uniform(-5, 5, (8000, 1)), np.full((8000, 1), -1.8)]
    box = np.c_[rng.uniform(74, 76, (200, 1)), rng.uniform(-1, 1, (200, 1)), rng.uniform(-1.2, -0.4, (200, 1))]
    sweep = _sweep(np.concatenate([road, box]))
    config = LidarMotionConfig()
    keys, heights = ground_heights([sweep], config.ground_cell, config.ground_rank)
    pts, _ = object_points(sweep, keys, heights, config)
    assert np.sum(pts[:, 0] > 73) == 200
    near, _ = object_points(sweep, keys, heights, dataclasses.replace(config, max_range=60.0))
    assert np.sum(near[:, 0] > 73) == 0


def test_fits_footprint_along_the_direction_of_motion():
    rng = np.random.default_rng(3)
    car = np.c_[rng.uniform(-2.2, 2.2, (300, 1)), rng.uniform(-0.9, 0.9, (300, 1)), np.zeros((300, 1))]
    yaw = np.radians(35.0)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    heading = R[:2, 0] * 8.0
    assert fits_footprint(car @ R.T + [10.0, 5.0, 0.0], (5.0, 2.5), heading)  # a turned car fits
    assert not fits_footprint(car @ R.T, (5.0, 2.5), R[:2, 1])  # moving sideways it would be 4.4 m wide
    assert fits_footprint(car @ R.T, (5.0, 2.5), np.zeros(2))  # no heading: its principal axes
    side_by_side = np.concatenate([car, car + [0.0, 3.5, 0.0]])  # two cars in neighbouring lanes
    assert not fits_footprint(side_by_side, (5.0, 2.5), np.array([8.0, 0.0]))
    nose_to_tail = np.concatenate([car, car + [5.5, 0.0, 0.0]])
    assert not fits_footprint(nose_to_tail, (5.0, 2.5), np.array([8.0, 0.0]))
    small_abreast = np.concatenate([car[:, :] * [0.3, 0.5, 1.0], car * [0.3, 0.5, 1.0] + [0.0, 3.0, 0.0]])
    assert not fits_footprint(small_abreast, (5.0, 2.5), np.array([8.0, 0.0]))  # two riders abreast


def test_rear_face_and_roof_of_one_car_merge_but_two_cars_abreast_do_not():
    config = LidarMotionConfig()
    # A car 4.5 m long driving along +x at 8 m/s, followed from behind: its rear face (x in
    # [0, 0.1]) and its roof (x in [2.0, 3.2]); the rear window between them returns nothing, so
    # the pieces are 1.9 m apart, more than merge_distance.
    rear = _box_track(1, (0.1, 1.8, 1.0), (0.05, 0.0, 0.5), (8.0, 0.0, 0.0), seed=4)
    roof = _box_track(2, (1.2, 1.5, 0.05), (2.6, 0.0, 1.4), (8.0, 0.0, 0.0), seed=5)
    assert config.merge_distance < 1.9
    assert len(merge_parts([rear, roof], config)) == 1
    # The same pieces one behind the other on two cars abreast, 3.5 m apart: two objects.
    other = _box_track(3, (1.2, 1.5, 0.05), (2.6, 3.5, 1.4), (8.0, 0.0, 0.0), seed=6)
    assert len(merge_parts([rear, other], config)) == 2
    # A piece in the car's footprint moving the other way (an oncoming cyclist passing): apart.
    oncoming = _box_track(4, (1.2, 0.5, 1.0), (2.6, 0.0, 1.0), (-6.0, 0.0, 0.0), seed=7)
    assert len(merge_parts([rear, oncoming], config)) == 2


def test_parts_whose_centroids_jump_between_sweeps_still_merge():
    # Two pieces of one car at 8 m/s (1.6 m per 0.2 s sweep); the roof is found in the last two
    # sweeps only, and in the last one its cluster holds only its rear half, so its centroid
    # advances 1.2 m instead of 1.6 m in that step (0.4 m per sweep off the rear face's step),
    # while over the tracks' lives the speeds differ by 2 m/s only.
    config = LidarMotionConfig()
    rear = _box_track(1, (0.1, 1.8, 1.0), (0.05, 0.0, 0.5), (8.0, 0.0, 0.0), seed=8)
    roof = _box_track(2, (1.6, 1.5, 0.05), (2.6, 0.0, 1.4), (8.0, 0.0, 0.0), seed=9)
    last = roof.clusters[4]
    back = last.points[:, 0] < np.median(last.points[:, 0])
    roof.clusters = [roof.clusters[3], MotionCluster(4, last.points[back], last.times[back], 1.0)]
    assert np.linalg.norm(roof.mean_velocity()[:2] - rear.mean_velocity()[:2]) < config.merge_speed_difference
    assert len(merge_parts([rear, roof], config)) == 1


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


def test_tracks_are_lifted_from_their_own_points_with_the_pixel_each_lands_on(street, tmp_path):
    """Direct lifting: every observation point is one of its track's cluster points at that
    frame, painted with an image of the frame it projects into; nothing is lost to the masks'
    hulls, erosion or the largest-cluster rule, so it keeps at least what painting keeps."""
    from idsplat_ns.instances.masks.lidar_motion import LidarMotionMaskSource
    from idsplat_ns.instances.lidar_motion_lifting import lift_track_points
    from idsplat_ns.instances.lifting import LiftedInstances, LiftingConfig, lift_instances

    scene, _ = street
    config = LidarMotionConfig()
    masks = LidarMotionMaskSource(config).generate(scene, tmp_path / "masks", progress=False)
    own = lift_track_points(scene, tmp_path / "masks", masks.labels, LiftingConfig(), progress=False)
    painted = lift_instances(scene, masks, LiftingConfig(), progress=False)
    tracks = {tr.track_id: tr for tr in moving_tracks(scene, config)}
    assert own.observations and set(own.observations) <= set(tracks)
    sweep_frames = [s.frame_index for s in scene.lidar if s.num_rays > 0]
    for tid, observations in own.observations.items():
        assert own.labels[tid] == masks.labels[tid]
        clusters = {sweep_frames[c.frame]: c for c in tracks[tid].clusters}
        for o in observations:
            frame_index = int(scene.frame_indices[o.frame])
            cluster = {tuple(p) for p in clusters[frame_index].points}
            assert all(tuple(p) in cluster for p in o.points)
            assert o.seen_fraction == len(o.points) / len(clusters[frame_index].points)  # what the cameras kept
            for i in np.unique(o.image_ids):
                image = scene.images[i]
                assert scene.closest_sweep(image.time).frame_index == frame_index
                sel = o.image_ids == i
                proj = image.project(o.points[sel])
                assert proj.valid.all()
                np.testing.assert_allclose(proj.uv, o.uv[sel], atol=1e-3)
    own.save(tmp_path / "lifted.npz")  # the share kept travels through the stage cache
    again = LiftedInstances.load(tmp_path / "lifted.npz")
    assert [o.seen_fraction for v in again.observations.values() for o in v] == \
        [o.seen_fraction for v in own.observations.values() for o in v]
    n_own = sum(len(o.points) for v in own.observations.values() for o in v)
    n_painted = sum(len(o.points) for v in painted.observations.values() for o in v)
    assert n_own >= n_painted


def test_a_lidar_motion_cache_without_its_points_says_what_to_do(street, tmp_path):
    from idsplat_ns.errors import IDSplatError
    from idsplat_ns.instances.lidar_motion_lifting import lift_track_points
    from idsplat_ns.instances.lifting import LiftingConfig

    scene, _ = street
    with pytest.raises(IDSplatError, match="track_points.npz: missing; delete"):
        lift_track_points(scene, tmp_path, {}, LiftingConfig(), progress=False)


def test_a_walking_persons_track_needs_less_displacement_than_a_cars():
    from idsplat_ns.instances.lidar_motion import min_displacement
    from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack

    rng = np.random.default_rng(0)

    def track(half_length: float, half_width: float, height: float, step: float) -> MotionTrack:
        clusters = []
        for k in range(10):  # one second at 10 Hz
            body = rng.uniform([-half_length, -half_width, 0.3], [half_length, half_width, height], size=(60, 3))
            clusters.append(MotionCluster(k, body + [step * k, 0.0, 0.0], np.full(60, 0.1 * k)))
        return MotionTrack(1, clusters)

    person = track(0.25, 0.25, 1.8, 0.13)  # 1.3 m/s
    car = track(2.2, 0.9, 1.5, 0.13)
    assert person.label() == "pedestrian" and car.label() == "car"
    unset = LidarMotionConfig(min_displacement_person=None)
    default = LidarMotionConfig()
    assert min_displacement(person, unset) == min_displacement(car, unset) == unset.min_displacement == 1.5
    assert min_displacement(person, default) == 1.0  # the default
    assert min_displacement(car, default) == 1.5
    assert person.displacement() > 1.0  # the person of 1 s at 1.3 m/s now moves; before it did not


def test_a_track_handed_over_on_a_turn_merges_but_cars_abreast_do_not():
    from idsplat_ns.instances.lidar_motion import _parts_of_one_object
    from idsplat_ns.instances.motion_tracks import LidarMotionConfig, MotionCluster, MotionTrack

    rng = np.random.default_rng(1)

    def blob(frame: int, centre) -> MotionCluster:
        pts = np.asarray(centre, float) + rng.uniform([-1.0, -0.5, 0.3], [1.0, 0.5, 1.5], size=(40, 3))
        return MotionCluster(frame, pts, np.full(40, 0.1 * frame))

    # A car's first piece creeps (its visible part grows: 1 m/s), the second drives on at 5 m/s in
    # about the same direction; they share two sweeps where their clusters touch.
    first = MotionTrack(1, [blob(k, [0.1 * k, 0.0, 0.0]) for k in range(10)])
    second = MotionTrack(2, [blob(k, [1.3 + 0.5 * (k - 8), 0.06 * (k - 8), 0.0]) for k in range(8, 20)])
    hand_over = LidarMotionConfig(merge_hand_over_sweeps=2)
    assert np.linalg.norm(first.mean_velocity()[:2] - second.mean_velocity()[:2]) > hand_over.merge_speed_difference
    assert not _parts_of_one_object(first, second, LidarMotionConfig(merge_hand_over_sweeps=0))
    assert _parts_of_one_object(first, second, hand_over)
    # Cars abreast (an overtaking, 4 m/s faster, 2 m to the side) share many sweeps: never handed over.
    slow = MotionTrack(3, [blob(k, [1.0 * k, 0.0, 0.0]) for k in range(12)])
    fast = MotionTrack(4, [blob(k, [1.4 * k - 2.4, 2.0, 0.0]) for k in range(6, 12)])
    assert not _parts_of_one_object(slow, fast, hand_over)
    # Two sweeps shared at the end of one and the start of the other, but heading the other way.
    oncoming = MotionTrack(5, [blob(k, [1.3 - 0.5 * (k - 8), 0.0, 0.0]) for k in range(8, 20)])
    assert not _parts_of_one_object(first, oncoming, hand_over)


def test_a_thin_person_is_a_cluster_when_asked_and_a_pole_never():
    """A person seen from one side is narrower than ``min_footprint`` in every direction, as a pole
    is; ``thin_max_height`` keeps the one whose points span a person's height, not the pole's."""
    rng = np.random.default_rng(4)
    person = np.c_[rng.uniform(0, 0.3, 120), rng.uniform(0, 0.25, 120), rng.uniform(0.3, 1.6, 120)]
    pole = np.c_[rng.uniform(5, 5.15, 150), rng.uniform(0, 0.15, 150), rng.uniform(0.3, 3.8, 150)]
    car = np.c_[rng.uniform(10, 14, 400), rng.uniform(0, 1.8, 400), rng.uniform(0.3, 1.4, 400)]
    points = np.concatenate([person, pole, car])
    times = np.zeros(len(points))

    def centres(config):
        return sorted(round(float(c.points[:, 0].mean())) for c in cluster_sweep(points, times, 0, config))

    assert centres(LidarMotionConfig()) == [12]
    assert centres(LidarMotionConfig(thin_max_height=1.5)) == [0, 12]


def test_a_persons_track_drops_the_views_where_it_joined_a_neighbours_cluster():
    """A track whose median cluster is person-wide keeps only its person-sized clusters (a walker
    merged with a parked car for a sweep); a car's track keeps its narrow first views."""
    rng = np.random.default_rng(6)

    def cluster(frame, width):
        return MotionCluster(frame, np.c_[rng.uniform(0, width, 40), rng.uniform(0, 0.3, 40), rng.uniform(0.3, 1.6, 40)],
                             np.zeros(40))

    walker = MotionTrack(1, [cluster(k, w) for k, w in enumerate([0.4, 0.3, 3.8, 0.5, 0.4])])
    kept = person_views(walker, 0.6)
    assert [c.frame for c in kept.clusters] == [0, 1, 3, 4]
    car = MotionTrack(2, [cluster(k, w) for k, w in enumerate([0.5, 1.2, 3.9, 4.4, 4.5])])
    assert person_views(car, 0.6) is car


def test_a_u_turn_split_in_two_hands_over_by_the_velocities_where_the_halves_meet():
    from idsplat_ns.instances.lidar_motion import _parts_of_one_object

    rng = np.random.default_rng(2)

    def blob(frame: int, centre) -> MotionCluster:
        pts = np.asarray(centre, float) + rng.uniform([-1.0, -0.5, 0.3], [1.0, 0.5, 1.5], size=(40, 3))
        return MotionCluster(frame, pts, np.full(40, 0.1 * frame))

    # A car drives along +x at 5 m/s, makes a U-turn (a half circle of 4 m radius about (0, 4) in
    # sweeps 8-16) and drives back along -x; its track breaks at sweep 11, mid-turn.
    def centre(k: int) -> list:
        if k <= 8:
            return [0.5 * k - 4.0, 0.0, 0.0]
        angle = min((k - 8) * np.pi / 8, np.pi)
        if angle < np.pi:
            return [4.0 * np.sin(angle), 4.0 - 4.0 * np.cos(angle), 0.0]
        return [-0.5 * (k - 16), 8.0, 0.0]

    first = MotionTrack(1, [blob(k, centre(k)) for k in range(0, 12)])
    second = MotionTrack(2, [blob(k, centre(k)) for k in range(11, 24)])
    assert float(first.mean_velocity()[:2] @ second.mean_velocity()[:2]) < 0  # opposite over their lives
    whole_lives = LidarMotionConfig(merge_hand_over_sweeps=2, hand_over_velocity_sweeps=0)
    assert not _parts_of_one_object(first, second, whole_lives)
    assert _parts_of_one_object(first, second, LidarMotionConfig(merge_hand_over_sweeps=2, hand_over_velocity_sweeps=3))
    # Two cars meeting head-on at a junction sweep still head opposite ways there.
    oncoming = MotionTrack(3, [blob(k, [float(centre(11)[0]) - 0.5 * (k - 11), float(centre(11)[1]), 0.0]) for k in range(11, 24)])
    incoming = MotionTrack(4, [blob(k, [float(centre(11)[0]) + 0.5 * (k - 11), float(centre(11)[1]), 0.0]) for k in range(0, 12)])
    assert not _parts_of_one_object(incoming, oncoming, LidarMotionConfig(merge_hand_over_sweeps=2, hand_over_velocity_sweeps=3))
