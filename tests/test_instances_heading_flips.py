"""Front/back flip detection from the direction of travel, the half turn that undoes a flip, and
its use after registration (canonical points re-mapped)."""

from __future__ import annotations

import math

import numpy as np

from _instances_fixtures import CAR_SIZE, box_surface
from idsplat_ns.data.geometry import invert_pose, make_pose, rot_z, transform_points, wrap_angle, yaw_of
from idsplat_ns.instances.heading_flips import (
    HeadingFlipConfig, detect_flips, flip_about, travel_directions,
)
from idsplat_ns.instances.lifting import InstanceObservation
from idsplat_ns.instances.trajectory_estimation import TrajectoryConfig, _correct_flips


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
    d = travel_directions(t, poses[:, :3, 3], valid, min_displacement=0.5, max_time_gap=2.0)
    assert np.isnan(d[5])
    heading = 6.0 * t / 15.0
    # the chord to the nearest measurement 0.5 m+ away lies within its half-angle of the tangent
    assert np.all(np.abs((d[valid] - heading[valid] + np.pi) % (2 * np.pi) - np.pi) < 0.1)
    # a parked car has no direction of travel
    still = np.tile(np.eye(4), (5, 1, 1))
    assert np.isnan(travel_directions(np.arange(5.0), still[:, :3, 3], np.ones(5, bool), 0.5, 2.0)).all()


def test_detect_flips_finds_exactly_the_flipped_measurements():
    t, poses = _turning_track()
    valid = np.ones(len(t), bool)
    truth = np.zeros(len(t), bool)
    truth[[0, 1, 2, 9]] = True
    flipped_poses = poses.copy()
    for k in np.flatnonzero(truth):
        flipped_poses[k] = flip_about(poses[k], np.array([0.3, -0.2, 0.0]))
    weights = np.full(len(t), 100.0)
    found = detect_flips(t, flipped_poses, valid, weights, HeadingFlipConfig())
    np.testing.assert_array_equal(found, truth)
    # no flips: nothing found; the common offset does not depend on the shared rotation
    for shared in (0.0, 2.5, -1.9):
        _, clean = _turning_track(shared_yaw=shared)
        assert not detect_flips(t, clean, valid, weights, HeadingFlipConfig()).any()


def test_weights_decide_which_half_is_flipped():
    t, poses = _turning_track(num=10)
    valid = np.ones(10, bool)
    flipped_poses = poses.copy()
    for k in range(6):  # the majority is flipped, but carries few points
        flipped_poses[k] = flip_about(poses[k], np.zeros(3))
    weights = np.array([10.0] * 6 + [500.0] * 4)
    found = detect_flips(t, flipped_poses, valid, weights, HeadingFlipConfig())
    np.testing.assert_array_equal(found, np.arange(10) < 6)


def test_flip_about_turns_half_a_turn_about_the_centre():
    pose = make_pose(rot_z(0.4), np.array([5.0, -2.0, 1.0]))
    c = np.array([1.2, -0.4, 0.7])
    out = flip_about(pose, c)
    assert math.isclose(abs(wrap_angle(yaw_of(out) - 0.4)), np.pi, abs_tol=1e-9)
    c_ground = np.array([c[0], c[1], 0.0])
    np.testing.assert_allclose(transform_points(out, c_ground[None]), transform_points(pose, c_ground[None]), atol=1e-12)
    np.testing.assert_allclose(flip_about(out, c), pose, atol=1e-12)  # twice is the identity


def test_correct_flips_restores_poses_and_remaps_canonical_points():
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
        registered[k] = flip_about(poses[k], np.zeros(3))
    valid = np.ones(12, bool)
    fitness = np.ones(12)
    counts = np.full(12, len(body))
    canon_frames = list(range(12))
    canon_pts = [transform_points(invert_pose(registered[k]), observations[k].points) for k in canon_frames]
    cols = [None] * 12
    _correct_flips(registered, valid, fitness, counts, canon_pts, cols, canon_frames, observations, t, TrajectoryConfig())
    for k in range(12):
        np.testing.assert_allclose(registered[k][:3, 3], poses[k][:3, 3], atol=0.05)
        assert abs(wrap_angle(yaw_of(registered[k]) - yaw_of(poses[k]))) < 0.02
        np.testing.assert_allclose(canon_pts[k], body, atol=0.06)
    assert np.all(fitness[flipped] > 0.9)


def test_correct_flips_leaves_a_parked_car_alone():
    t = np.arange(8) * 0.2
    poses = np.tile(make_pose(rot_z(0.3), np.array([4.0, 2.0, 0.0])), (8, 1, 1))
    poses[3] = flip_about(poses[3], np.zeros(3))
    before = poses.copy()
    pts = [np.zeros((5, 3)) for _ in range(8)]
    _correct_flips(poses, np.ones(8, bool), np.ones(8), np.full(8, 50), pts, [None] * 8, list(range(8)), {}, t, TrajectoryConfig())
    np.testing.assert_array_equal(poses, before)
