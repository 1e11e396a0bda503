"""Amodal canonical origins: a vehicle seen from one end gets its origin half a length behind it."""

from __future__ import annotations

import numpy as np
import pytest

from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.instances.amodal_centre import (
    AmodalCentreConfig, amodal_centre, complete_centres, shift_origin, travel_direction, typical_size,
)  # fmt: skip
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks

LENGTH, WIDTH, HEIGHT = 4.5, 1.85, 1.5


def _rear_face(rng: np.random.Generator, n: int = 400) -> np.ndarray:  # -> [n, 3] in the body frame (x forward)
    return np.stack([np.full(n, -LENGTH / 2), rng.uniform(-WIDTH / 2, WIDTH / 2, n), rng.uniform(-HEIGHT / 2, HEIGHT / 2, n)], 1)


def _left_side(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    return np.stack([rng.uniform(-LENGTH / 2, LENGTH / 2, n), np.full(n, WIDTH / 2), rng.uniform(-HEIGHT / 2, HEIGHT / 2, n)], 1)


def test_typical_size_by_keyword():
    assert typical_size("Car") == (4.5, 1.85)
    assert typical_size("pickup truck")[0] == 5.5  # 'pickup' comes before 'truck'
    assert typical_size("Bus")[0] == 12.0
    assert typical_size("traffic cone") is None


def test_followed_car_seen_from_behind_is_completed():
    rng = np.random.default_rng(0)
    yaw = np.radians(30.0)
    R = rot_z(yaw)
    # canonical frame = world axes, origin at the middle of the visible rear face (the paper's choice)
    rear = _rear_face(rng) @ R.T
    origin = 0.5 * (rear.min(0) + rear.max(0))
    points = rear - origin
    forward = R[:, 0]
    true_centre = -origin  # the body centre in this canonical frame
    sensor = true_centre - 12.0 * forward  # the ego drives 12 m behind
    c = amodal_centre(points, forward, sensor[None], LENGTH, WIDTH, trim=0.0)
    np.testing.assert_allclose(c[:2], true_centre[:2], atol=0.05)
    # the same face seen by a sensor ahead of the car (an oncoming car's front): completed the other way
    c_front = amodal_centre(points, forward, (true_centre + 12.0 * forward)[None], LENGTH, WIDTH, trim=0.0)
    np.testing.assert_allclose((c_front - c)[:2] @ forward[:2], -LENGTH, atol=0.05)


def test_side_view_keeps_the_middle():
    rng = np.random.default_rng(1)
    side = _left_side(rng)
    sensor = np.array([[0.0, 8.0, 0.0]])  # beside the car, left of it
    c = amodal_centre(side, np.array([1.0, 0.0, 0.0]), sensor, LENGTH, WIDTH, trim=0.0)
    assert abs(c[0]) < 0.05  # full length seen: middle along x
    assert c[1] == pytest.approx(0.0, abs=0.05)  # face at +W/2 seen from the left: body centre W/2 to its right


def test_travel_direction_ignores_sign_and_stops():
    F = 6
    poses = np.stack([make_pose(rot_z(0.3), np.array([2.0 * k, 0.0, 0.0])) for k in range(F)])
    d = travel_direction(poses, np.ones(F, bool))
    np.testing.assert_allclose(d, rot_z(0.3).T @ np.array([1.0, 0.0, 0.0]), atol=1e-9)
    reversed_poses = poses[::-1].copy()
    np.testing.assert_allclose(np.abs(travel_direction(reversed_poses, np.ones(F, bool))), np.abs(d), atol=1e-9)
    still = np.stack([make_pose(np.eye(3), np.array([0.01 * k, 0.0, 0.0])) for k in range(F)])
    assert travel_direction(still, np.ones(F, bool)) is None


def test_complete_centres_moves_origin_not_points():
    rng = np.random.default_rng(2)
    F = 5
    rear = _rear_face(rng)
    origin = 0.5 * (rear.min(0) + rear.max(0))
    poses = np.stack([make_pose(np.eye(3), origin + np.array([3.0 * k, 10.0, 0.0])) for k in range(F)])
    inst = InstanceTrack(1, "car", rear - origin, None, poses, np.ones(F, bool), np.full(F, 400), np.ones(F), 0)
    parked = InstanceTrack(2, "car", rear - origin, None, poses, np.ones(F, bool), np.full(F, 400), np.ones(F), 0)
    tracks = InstanceTracks(np.arange(F), np.arange(F) * 0.1, [inst], [parked], {})
    sensors = np.stack([np.array([3.0 * k - 10.0, 10.0, 0.0]) for k in range(F)])  # following 10 m behind
    out = complete_centres(tracks, sensors)
    done = out.instance(1)
    # every point keeps its world position
    for k in range(F):
        before = inst.canonical_points @ inst.poses[k, :3, :3].T + inst.poses[k, :3, 3]
        after = done.canonical_points @ done.poses[k, :3, :3].T + done.poses[k, :3, 3]
        np.testing.assert_allclose(after, before, atol=1e-9)
    # the origin is now the body centre (the truth: x = 3k + 0, y = 10)
    np.testing.assert_allclose(done.poses[:, 0, 3], 3.0 * np.arange(F), atol=0.05)
    assert out.static_instances[0] is parked  # static instances are left alone
    assert out.metadata["amodal_centre_shift"][1][0] == pytest.approx(LENGTH / 2, abs=0.05)
    assert complete_centres(tracks, sensors, AmodalCentreConfig(enabled=False)) is tracks


def test_shift_origin_round_trip():
    pts = np.random.default_rng(3).normal(size=(10, 3))
    poses = np.stack([make_pose(rot_z(0.1 * k), np.array([k, 2.0, 0.0])) for k in range(3)])
    c = np.array([0.5, -0.2, 0.1])
    p2, q2 = shift_origin(pts, poses, c)
    p3, q3 = shift_origin(p2, q2, -c)
    np.testing.assert_allclose(p3, pts, atol=1e-12)
    np.testing.assert_allclose(q3, poses, atol=1e-12)


def _trailer_rear(rng: np.random.Generator, length: float, height: float, underside: float, n: int = 600) -> np.ndarray:
    """The rear face of a box of ``length`` x 2.5 m x ``height`` standing on the ground (z = 0), in
    the body frame (x forward, origin at the box centre on the ground), with nothing seen below
    ``underside`` (a trailer's open underside)."""
    return np.stack([np.full(n, -length / 2), rng.uniform(-1.25, 1.25, n), rng.uniform(underside, height, n)], 1)


@pytest.mark.parametrize("height, expected_length", [(3.9, 16.5), (3.1, 12.0)])
def test_a_long_vehicle_taller_than_the_roof_height_is_completed_to_the_tall_size(height, expected_length):
    # A 16.5 m lorry and a 12 m bus followed from 30 m behind, labelled "bus" (a tall end-on face):
    # with the lidar ground, the lorry's 3.9 m roof gives it the tall size, the bus keeps its own.
    rng = np.random.default_rng(4)
    frames = 6
    rear = _trailer_rear(rng, expected_length, height, underside=1.0)
    origin = 0.5 * (rear.min(0) + rear.max(0))  # the paper's origin: middle of the seen face
    poses = np.stack([make_pose(np.eye(3), origin + np.array([2.0 * k, 0.0, 0.0])) for k in range(frames)])
    inst = InstanceTrack(1, "bus", rear - origin, None, poses, np.ones(frames, bool), np.full(frames, 600), np.ones(frames), 0)
    tracks = InstanceTracks(np.arange(frames), np.arange(frames) * 0.1, [inst], [], {})
    sensors = np.stack([np.array([2.0 * k - 30.0, 0.0, 1.8]) for k in range(frames)])
    flat_ground = lambda xy: np.zeros(len(xy))  # noqa: E731
    config = AmodalCentreConfig(tall_roof_height=3.5, ground_contact=True)
    done = complete_centres(tracks, sensors, config, flat_ground).instance(1)
    # The true box centre: x = 2k (body origin), y = 0, z = height / 2 above the ground.
    np.testing.assert_allclose(done.poses[:, 0, 3], 2.0 * np.arange(frames), atol=0.05)
    np.testing.assert_allclose(done.poses[:, 2, 3], height / 2, atol=0.05)
    # Without the ground neither the roof nor the underside is known: the bus length, the seen middle.
    plain = complete_centres(tracks, sensors, config).instance(1)
    np.testing.assert_allclose(plain.poses[:, 0, 3], 2.0 * np.arange(frames) - (expected_length - 12.0) / 2, atol=0.05)
    np.testing.assert_allclose(plain.poses[:, 2, 3], (1.0 + height) / 2, atol=0.05)


def test_ground_contact_follows_the_ground_under_each_frame_and_ignores_unknown_ground():
    rng = np.random.default_rng(5)
    frames = 5
    rear = _rear_face(rng) + np.array([0.0, 0.0, HEIGHT / 2])  # standing on z = 0, bottom 0.4 m unseen
    rear = rear[rear[:, 2] > 0.4]
    origin = 0.5 * (rear.min(0) + rear.max(0))
    # A road climbing 1 m per frame along x; the car follows it.
    poses = np.stack([make_pose(np.eye(3), origin + np.array([3.0 * k, 0.0, 1.0 * k])) for k in range(frames)])
    inst = InstanceTrack(1, "car", rear - origin, None, poses, np.ones(frames, bool), np.full(frames, 400), np.ones(frames), 0)
    tracks = InstanceTracks(np.arange(frames), np.arange(frames) * 0.1, [inst], [], {})
    sensors = np.stack([np.array([3.0 * k - 12.0, 0.0, 1.8 + k]) for k in range(frames)])
    # The ground under the seen face's middle (x = 3k - L/2) is at z = k; unknown at the first frame.
    ground = lambda xy: np.where(np.arange(len(xy)) == 0, np.nan, (xy[:, 0] + LENGTH / 2) / 3.0)  # noqa: E731
    done = complete_centres(tracks, sensors, AmodalCentreConfig(ground_contact=True), ground).instance(1)
    np.testing.assert_allclose(done.poses[:, 2, 3], np.arange(frames) + HEIGHT / 2, atol=0.05)
    off = complete_centres(tracks, sensors, AmodalCentreConfig(ground_contact=False), ground).instance(1)  # the seen middle
    np.testing.assert_allclose(off.poses[:, 2, 3], np.arange(frames) + (0.4 + HEIGHT) / 2, atol=0.05)
