"""Heading errors found from the direction of travel (front/back flips, quarter turns), the turn
that undoes them, and their correction after registration (canonical points re-mapped)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from _instances_fixtures import CAR_SIZE, box_surface
from idsplat_ns.data.geometry import invert_pose, make_pose, rot_z, transform_points, wrap_angle, yaw_of
from idsplat_ns.instances.heading_flips import (
    HeadingFlipConfig, heading_errors, travel_directions, turn_about,
)
from idsplat_ns.instances.lifting import InstanceObservation
from idsplat_ns.instances.track_builder import TrackBuilder
from idsplat_ns.instances.trajectory_config import TrajectoryConfig
from idsplat_ns.instances.trajectory_passes import correct_headings, turn_centre


def _turning_track(num: int = 16, dt: float = 0.2, shared_yaw: float = 0.7):
    """A car on a quarter circle (radius 15 m, 6 m/s); poses' yaw = heading - shared_yaw (the
    canonical x axis is not the car's forward axis, as after registration)."""
    t = np.arange(num) * dt
    angle = 6.0 * t / 15.0
    pos = np.stack([15 * np.sin(angle), 15 * (1 - np.cos(angle)), np.zeros(num)], 1)
    heading = angle
    poses = make_pose(rot_z(heading - shared_yaw), pos)
    return t, poses


def test_travel_directions_follow_the_motion():
    t, poses = _turning_track()
    valid = np.ones(len(t), bool)
    valid[5] = False
    heading = 6.0 * t / 15.0
    # a chord k steps long (1.2 m, 0.08 rad of turn per step) lies k * 0.04 rad off the tangent
    nearest = travel_directions(t, poses[:, :3, 3], valid, min_displacement=0.5, max_time_gap=2.0, neighbours=1,
                                min_agreement=0.5)
    assert np.isnan(nearest[5])
    assert np.all(np.abs(wrap_angle(nearest[valid] - heading[valid])) < 0.1)
    # the mean over 4 neighbours: chords on both sides cancel inside the track; one-sided at the
    # ends it lies (1 + 2 + 3 + 4) / 4 * 0.04 = 0.1 rad off
    d = travel_directions(t, poses[:, :3, 3], valid, min_displacement=0.5, max_time_gap=2.0, neighbours=4,
                          min_agreement=0.5)
    err = np.abs(wrap_angle(d - heading))
    assert np.isnan(d[5]) and np.all(err[valid] < 0.11)
    assert np.all(err[[2, 8, 9, 10, 11]] < 1e-6)  # symmetric neighbourhoods (away from the gap at 5)
    # a parked car has no direction of travel
    still = np.tile(np.eye(4), (5, 1, 1))
    assert np.isnan(travel_directions(np.arange(5.0), still[:, :3, 3], np.ones(5, bool), 0.5, 2.0, 4, 0.5)).all()


def test_heading_errors_find_exactly_the_flipped_measurements():
    t, poses = _turning_track()
    valid = np.ones(len(t), bool)
    truth = np.zeros(len(t), bool)
    truth[[0, 1, 2, 9]] = True
    flipped_poses = poses.copy()
    for k in np.flatnonzero(truth):
        flipped_poses[k] = turn_about(poses[k], np.array([0.3, -0.2, 0.0]), np.pi)
    weights = np.full(len(t), 100.0)
    found = heading_errors(t, flipped_poses, valid, weights, HeadingFlipConfig())
    np.testing.assert_array_equal(np.isfinite(found), truth)
    np.testing.assert_allclose(np.abs(found[truth]), np.pi)  # snapped to the half turn
    # no flips: nothing found; the common offset does not depend on the shared rotation
    for shared in (0.0, 2.5, -1.9):
        _, clean = _turning_track(shared_yaw=shared)
        assert np.isnan(heading_errors(t, clean, valid, weights, HeadingFlipConfig())).all()


def test_weights_decide_which_half_is_flipped():
    t, poses = _turning_track(num=10)
    valid = np.ones(10, bool)
    flipped_poses = poses.copy()
    for k in range(6):  # the majority is flipped, but carries few points
        flipped_poses[k] = turn_about(poses[k], np.zeros(3), np.pi)
    weights = np.array([10.0] * 6 + [500.0] * 4)
    found = heading_errors(t, flipped_poses, valid, weights, HeadingFlipConfig())
    np.testing.assert_array_equal(np.isfinite(found), np.arange(10) < 6)


@pytest.mark.parametrize("angle", [np.pi, np.pi / 2, -0.3])
def test_turn_about_turns_about_the_centre(angle):
    pose = make_pose(rot_z(0.4), np.array([5.0, -2.0, 1.0]))
    c = np.array([1.2, -0.4, 0.7])
    out = turn_about(pose, c, angle)
    assert math.isclose(wrap_angle(yaw_of(out) - 0.4 - angle), 0.0, abs_tol=1e-9)
    c_ground = np.array([c[0], c[1], 0.0])
    np.testing.assert_allclose(transform_points(out, c_ground[None]), transform_points(pose, c_ground[None]), atol=1e-12)
    np.testing.assert_allclose(turn_about(out, c, -angle), pose, atol=1e-12)  # undone by the opposite turn


def test_one_misplaced_measurement_does_not_reverse_its_neighbours():
    """Recorded on the small street, seed 4: a car entering the view was registered 3.5 m ahead
    of itself. With the direction towards the nearest neighbour alone, it and its (correct)
    neighbour both seemed to drive backwards, so both were 'flipped' and then dropped."""
    t, poses = _turning_track(num=10, shared_yaw=0.0)
    poses[0, :3, 3] += 3.5 * np.array([1.0, 0.0, 0.0])  # ahead of frame 1
    valid = np.ones(10, bool)
    d_nearest = travel_directions(t, poses[:, :3, 3], valid, 0.5, 2.0, neighbours=1, min_agreement=0.5)
    assert abs(wrap_angle(d_nearest[1])) > np.pi / 2  # the old rule: frame 1 drives backwards
    assert np.isnan(heading_errors(t, poses, valid, np.full(10, 100.0), HeadingFlipConfig())).all()


def test_quarter_turns_are_found_and_snapped():
    t, poses = _turning_track(num=12)
    registered = poses.copy()
    for k in range(4):  # sparse early frames registered a quarter turn off (plus a little)
        registered[k] = turn_about(poses[k], np.zeros(3), -np.pi / 2 + 0.15)
    weights = np.array([20.0] * 4 + [300.0] * 8)
    found = heading_errors(t, registered, np.ones(12, bool), weights, HeadingFlipConfig())
    np.testing.assert_array_equal(np.isfinite(found), np.arange(12) < 4)
    np.testing.assert_allclose(found[:4], np.pi / 2)
    # without snapping the turn is the measured disagreement, which carries the chord's error
    raw = heading_errors(t, registered, np.ones(12, bool), weights, HeadingFlipConfig(snap_angle=0.0))
    assert np.all(np.abs(raw[:4] - (np.pi / 2 - 0.15)) < 0.11)  # the chord's error, above


def test_correct_headings_restores_poses_and_remaps_canonical_points():
    rng = np.random.default_rng(0)
    t, poses = _turning_track(num=12, shared_yaw=0.0)
    body = box_surface(1500, CAR_SIZE, rng)
    # asymmetric body so that ICP has a unique answer: a cabin on the rear half
    cabin = box_surface(400, np.array([2.0, 1.6, 0.6]), rng) + np.array([-0.8, 0.0, 1.0])
    body = np.concatenate([body, cabin])
    observations = {k: InstanceObservation(k, transform_points(poses[k], body), np.zeros(len(body), np.int32),
                                           np.zeros((len(body), 2), np.float32)) for k in range(12)}
    registered = poses.copy()
    flipped = [1, 2, 7]
    for k in flipped:
        registered[k] = turn_about(poses[k], np.zeros(3), np.pi)
    builder = TrackBuilder.registered(observations, registered, t)
    correct_headings(builder, TrajectoryConfig())
    assert builder.frames == list(range(12))
    for k in range(12):
        np.testing.assert_allclose(builder.poses[k][:3, 3], poses[k][:3, 3], atol=0.05)
        assert abs(wrap_angle(yaw_of(builder.poses[k]) - yaw_of(poses[k]))) < 0.02
        np.testing.assert_allclose(builder.chunks[k].points, body, atol=0.06)
    assert np.all(builder.fitness[flipped] > 0.9)


def test_correct_headings_leaves_a_parked_car_alone():
    t = np.arange(8) * 0.2
    poses = np.tile(make_pose(rot_z(0.3), np.array([4.0, 2.0, 0.0])), (8, 1, 1))
    poses[3] = turn_about(poses[3], np.zeros(3), np.pi)
    before = poses.copy()
    observations = {k: InstanceObservation(k, np.zeros((50, 3)), np.zeros(50, np.int32), np.zeros((50, 2), np.float32))
                    for k in range(8)}
    builder = TrackBuilder.registered(observations, poses, t)
    correct_headings(builder, TrajectoryConfig())
    np.testing.assert_array_equal(builder.poses, before)



def test_heading_turns_are_about_the_vehicle_centre_not_the_seen_part():
    """A car seen from its right side and rear, at 0.4 rad to the canonical axes (registration's
    canonical frame has the world's axes at the densest frame): the middle of its points' box is
    off its centre, and a 180° turn about that middle would misplace the turned frames by twice as
    much (seed 5 of the small street: 0.9 m, and 10 far frames 1.8 m off)."""
    rng = np.random.default_rng(5)
    body = np.concatenate([box_surface(4000, CAR_SIZE, rng),
                           box_surface(800, np.array([2.0, 1.6, 0.6]), rng) + np.array([-0.8, 0.0, 1.0])])
    half = CAR_SIZE / 2
    seen = body[(body[:, 1] > half[1] - 1e-6) | (body[:, 0] < -half[0] + 1e-6)]  # right side, rear
    t, car = _turning_track(num=12, shared_yaw=0.0)
    ref = 6
    canonical_axes = make_pose(rot_z(-yaw_of(car[ref])), np.zeros(3))  # body -> canonical rotation at the reference
    in_canonical = transform_points(canonical_axes, seen)
    middle = 0.5 * (in_canonical.min(0) + in_canonical.max(0))
    body_to_canonical = make_pose(canonical_axes[:3, :3], -middle)
    poses = car @ invert_pose(body_to_canonical)  # canonical -> world
    points = in_canonical - middle
    true_centre = body_to_canonical[:3, 3]  # the car's centre in canonical coordinates
    assert np.linalg.norm(true_centre[:2]) > 0.3  # the middle of the points is off
    sensors = np.stack([transform_points(car[k], np.array([[-4.0, 8.0, 0.0]]))[0] for k in range(12)])  # right, behind
    centre = turn_centre(points, poses, list(range(12)), "Car", sensors)
    np.testing.assert_allclose(centre[:2], true_centre[:2], atol=0.15)
    # Without sensors or a known class, the middle of the points is all there is.
    for label, s in (("Car", None), ("thing", sensors)):
        np.testing.assert_allclose(turn_centre(points, poses, list(range(12)), label, s), 0.5 * (points.min(0) + points.max(0)))


def test_a_parked_car_with_slid_registrations_is_not_turned():
    """Registrations of a parked car slid 0.4 m a frame along it (more than the 1 m the
    displacement check allows) and one came out turned: its lidar points stay in place in the
    world, so it has no direction of travel and nothing is turned or dropped."""
    rng = np.random.default_rng(2)
    body = box_surface(800, CAR_SIZE, rng)
    parked = make_pose(rot_z(0.3), np.array([4.0, 2.0, 0.75]))
    world = transform_points(parked, body)
    t = np.arange(8) * 0.2
    slid = np.stack([parked @ make_pose(np.eye(3), np.array([0.4 * k, 0.0, 0.0])) for k in range(8)])
    slid[5] = turn_about(slid[5], np.zeros(3), np.pi)
    observations = {k: InstanceObservation(k, world + rng.normal(0, 0.01, world.shape), np.zeros(len(world), np.int32),
                                           np.zeros((len(world), 2), np.float32)) for k in range(8)}

    def correct(skip: bool):
        builder = TrackBuilder.registered(observations, slid, t)
        config = TrajectoryConfig(heading_flips=HeadingFlipConfig(skip_stationary=skip))
        correct_headings(builder, config)
        return builder.poses, builder.valid

    poses, valid = correct(True)
    np.testing.assert_array_equal(poses, slid)
    assert valid.all()
    poses, valid = correct(False)  # the check is what leaves it alone
    assert not (np.array_equal(poses, slid) and valid.all())
