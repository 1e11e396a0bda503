"""Which translations a registration measures (smoothing/observability.py), how the CT smoother
uses that, and the box heading that segment links are made along."""

from __future__ import annotations

import math

import numpy as np
import pytest

from idsplat_ns.data.geometry import rot_z
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.amodal_centre import box_heading
from idsplat_ns.instances.smoothing import SmoothingConfig, smooth_trajectory
from idsplat_ns.instances.registration import frame_surface_normals
from idsplat_ns.instances.smoothing.observability import (
    frame_information,
    measured_axes,
    one_sided_directions,
    translation_covariances,
)

LENGTH, WIDTH, HEIGHT = 4.5, 1.8, 1.4


def side(rng: np.random.Generator, n: int, x_range=(-LENGTH / 2, LENGTH / 2)) -> np.ndarray:  # -> [n, 3]
    """Points on the car's right side (y = -W/2), over ``x_range`` of its length."""
    return np.stack([rng.uniform(*x_range, n), np.full(n, -WIDTH / 2) + rng.normal(0, 0.005, n),
                     rng.uniform(0.3, HEIGHT, n)], 1)


def front(rng: np.random.Generator, n: int) -> np.ndarray:  # -> [n, 3]
    return np.stack([np.full(n, LENGTH / 2) + rng.normal(0, 0.005, n), rng.uniform(-WIDTH / 2, WIDTH / 2, n),
                     rng.uniform(0.3, HEIGHT, n)], 1)


def rear(rng: np.random.Generator, n: int) -> np.ndarray:  # -> [n, 3]
    return front(rng, n) * np.array([-1.0, 1.0, 1.0])


def test_frame_information_of_a_face_is_its_normal_and_of_a_corner_two_directions():
    rng = np.random.default_rng(0)
    points = np.concatenate([side(rng, 200), side(rng, 100), front(rng, 100)])
    frames = np.repeat([0, 1, 1], [200, 100, 100])
    info = frame_information(points, frames, 3)
    np.testing.assert_allclose(info[0], np.diag([0.0, 1.0, 0.0]), atol=0.05)  # a side: across only
    assert info[1][0, 0] > 0.3 and info[1][1, 1] > 0.3 and info[1][2, 2] < 0.05  # side + front
    assert np.all(info[2] == 0.0)  # no points
    axes, measured = measured_axes(info[0], 0.2)
    assert measured.sum() == 1 and abs(axes[:, measured][1, 0]) > 0.99
    axes, measured = measured_axes(info[1], 0.2)
    assert measured.sum() == 2
    assert measured_axes(np.zeros((3, 3)), 0.2)[1].all()  # nothing known: every axis, as the paper


def test_side_views_are_free_along_the_car_where_other_frames_measure_it_and_a_followed_car_is_not():
    rng = np.random.default_rng(1)
    sigma, big = 0.2, 3.0
    # Frames 0-2 see the side only, frames 3-5 side and front: 3-5 anchor the length.
    chunks = [side(rng, 60) for _ in range(3)] + [np.concatenate([side(rng, 80), front(rng, 60)]) for _ in range(3)]
    points, frames = np.concatenate(chunks), np.repeat(np.arange(6), [len(c) for c in chunks])
    cov = translation_covariances(points, frames, 7, sigma, 0.2, big)
    for f in range(3):
        assert math.sqrt(cov[f][0, 0]) == pytest.approx(big, rel=1e-3)  # along: left to the motion
        assert math.sqrt(cov[f][1, 1]) == pytest.approx(sigma, rel=1e-2)  # across: measured
        assert math.sqrt(cov[f][2, 2]) == pytest.approx(sigma, rel=1e-2)  # up: nothing measures it
    for f in range(3, 7):
        np.testing.assert_allclose(cov[f], np.eye(3) * sigma**2, atol=1e-9)
    # Followed from behind: the rear in every frame, nothing measures sideways: all kept.
    chunks = [rear(rng, 80) for _ in range(5)]
    points, frames = np.concatenate(chunks), np.repeat(np.arange(5), 80)
    np.testing.assert_allclose(translation_covariances(points, frames, 5, sigma, 0.2, big),
                               np.tile(np.eye(3) * sigma**2, (5, 1, 1)), atol=1e-9)
    # A frame of a handful of points measures nothing where others measure.
    chunks = [np.concatenate([side(rng, 80), front(rng, 60)]) for _ in range(3)] + [front(rng, 10)]
    points, frames = np.concatenate(chunks), np.repeat(np.arange(4), [len(c) for c in chunks])
    cov = translation_covariances(points, frames, 4, sigma, 0.2, big, min_frame_points=24)
    np.testing.assert_allclose(np.sqrt(np.diag(cov[3])), [big, big, sigma], rtol=0.05)  # up: nothing measures it


def _straight_car(speed: float = 5.0, steps: int = 12, dt: float = 0.1, yaw: float = 0.4):
    times = np.arange(steps) * dt
    poses = np.tile(np.eye(4), (steps, 1, 1))
    heading = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    for k in range(steps):
        poses[k, :3, :3] = rot_z(yaw)
        poses[k, :3, 3] = np.array([10.0, -4.0, 0.0]) + heading * speed * times[k]
    return times, poses, heading


def test_slid_side_views_are_smoothed_back_by_the_motion_and_do_not_end_the_span():
    """The first four frames see only the car's side and registered up to 2 m along it (seed 7's
    far turning car); the rest see side and front. With each frame's measured directions, the
    motion carries the side frames; with the paper's isotropic noise they pull the track."""
    rng = np.random.default_rng(2)
    times, truth, heading = _straight_car()
    measured = truth.copy()
    slide = np.array([2.0, 1.6, 1.2, 0.8])
    measured[:4, :3, 3] += slide[:, None] * heading
    chunks = [side(rng, 50, (-0.5, 2.25)) for _ in range(4)] + [
        np.concatenate([side(rng, 80), front(rng, 60)]) for _ in range(len(times) - 4)]
    points, frames = np.concatenate(chunks), np.repeat(np.arange(len(times)), [len(c) for c in chunks])
    config = SmoothingConfig()
    cov = translation_covariances(points, frames, len(times), config.measurement_trans_sigma,
                                  config.degenerate_ratio, config.degenerate_sigma)
    valid = np.ones(len(times), bool)
    plain = smooth_trajectory(times, measured, valid, config)
    informed = smooth_trajectory(times, measured, valid, config, cov)
    err = lambda sm: np.linalg.norm(sm.poses[:4, :3, 3] - truth[:4, :3, 3], axis=1)
    assert err(plain).max() > 0.8
    assert err(informed).max() < 0.25
    # The slid frames still begin the track, though further from the result than the span's
    # distance: a slide along what a frame does not measure counts for little.
    assert np.linalg.norm(informed.poses[0, :3, 3] - measured[0, :3, 3]) > config.span_max_distance
    assert informed.span[0] == pytest.approx(times[0])


def _front_then_rear(rng: np.random.Generator, fronts: int = 4, rears: int = 8, both: int | None = None):
    """A car that overtakes close: its side and front in the first frames, its side and rear in
    the rest (``both``: that frame sees front and rear). Returns points [N, 3], frames [N]."""
    chunks = [np.concatenate([side(rng, 80), front(rng, 50)]) for _ in range(fronts)]
    chunks += [np.concatenate([side(rng, 80), rear(rng, 50)]) for _ in range(rears)]
    if both is not None:
        chunks[both] = np.concatenate([side(rng, 80), front(rng, 50), rear(rng, 50)])
    return np.concatenate(chunks), np.repeat(np.arange(len(chunks)), [len(c) for c in chunks])


def test_front_frames_never_seen_with_the_rear_are_free_along_the_car():
    rng = np.random.default_rng(3)
    sigma, big = 0.2, 3.0
    points, frames = _front_then_rear(rng)
    directions = one_sided_directions(points, frames, frame_surface_normals(points, frames), 12)
    for f in range(4):  # the minority: along the car (x) only
        assert len(directions[f]) == 1 and abs(directions[f][0][0]) > 0.99
    assert all(len(directions[f]) == 0 for f in range(4, 12))
    cov = translation_covariances(points, frames, 12, sigma, 0.2, big)
    for f in range(4):  # 3 m along the car's axis as its faces give it (within a few degrees of x)
        values, vectors = np.linalg.eigh(cov[f])
        np.testing.assert_allclose(np.sqrt(values), [sigma, sigma, big], rtol=1e-6)
        assert abs(vectors[0, 2]) > 0.99
    np.testing.assert_allclose(cov[4:], np.tile(np.eye(3) * sigma**2, (8, 1, 1)), atol=1e-9)
    # The paper's view (and ours without the rule): the front measures the length.
    plain = translation_covariances(points, frames, 12, sigma, 0.2, big, one_sided_faces=False)
    np.testing.assert_allclose(plain, np.tile(np.eye(3) * sigma**2, (12, 1, 1)), atol=1e-9)


def test_one_frame_with_front_and_rear_ties_them_and_equal_groups_have_no_majority():
    rng = np.random.default_rng(4)
    points, frames = _front_then_rear(rng, both=5)
    normals = frame_surface_normals(points, frames)
    assert all(len(d) == 0 for d in one_sided_directions(points, frames, normals, 12))
    points, frames = _front_then_rear(rng, fronts=5, rears=5)
    normals = frame_surface_normals(points, frames)
    assert all(len(d) == 0 for d in one_sided_directions(points, frames, normals, 10))


def test_front_frames_registered_ahead_are_smoothed_back_by_the_rear_frames_motion():
    """Seed 9's overtaking car: merged through its side, the front frames registered 0.6-0.2 m
    ahead of the rear ones. Left to the motion along the car, they follow the rear frames' speed."""
    rng = np.random.default_rng(5)
    times, truth, heading = _straight_car(speed=12.0)
    measured = truth.copy()
    measured[:4, :3, 3] += np.array([0.6, 0.5, 0.4, 0.3])[:, None] * heading
    points, frames = _front_then_rear(rng, fronts=4, rears=len(times) - 4)
    config = SmoothingConfig()
    valid = np.ones(len(times), bool)
    errors = {}
    for one_sided in (False, True):
        cov = translation_covariances(points, frames, len(times), config.measurement_trans_sigma,
                                      config.degenerate_ratio, config.degenerate_sigma, one_sided_faces=one_sided)
        sm = smooth_trajectory(times, measured, valid, config, cov)
        errors[one_sided] = np.linalg.norm(sm.poses[:4, :3, 3] - truth[:4, :3, 3], axis=1).max()
    assert errors[False] > 0.3
    assert errors[True] < 0.1


def test_translation_covariances_of_wrong_shape_are_a_clear_error():
    times, poses, _ = _straight_car()
    with pytest.raises(ValueError, match="translation_covariances"):
        smooth_trajectory(times, poses, np.ones(len(times), bool), None, np.zeros((3, 3, 3)))


@pytest.mark.parametrize("field, value", [("degenerate_ratio", 1.5), ("degenerate_ratio", -0.1), ("degenerate_sigma", 0.0),
                                          ("degenerate_min_anchor_frames", -1)])
def test_degenerate_settings_are_checked(field, value):
    with pytest.raises(IDSplatError, match=field.replace("_", "-").replace("degenerate-min-anchor-frames", "min-anchor-frames")):
        SmoothingConfig(**{field: value})


def test_box_heading_snaps_a_skewed_direction_of_travel_onto_the_box():
    """The origin of a turning car moves up to 20 degrees off its heading; the box's faces say
    which way it points."""
    rng = np.random.default_rng(3)
    yaw = math.radians(30.0)
    R = rot_z(yaw)
    chunks = [side(rng, 80) @ R.T, np.concatenate([side(rng, 60), front(rng, 40)]) @ R.T]
    points, frames = np.concatenate(chunks), np.repeat([0, 1], [len(c) for c in chunks])
    for skew in (-25.0, 20.0):
        guess = np.array([math.cos(yaw + math.radians(skew)), math.sin(yaw + math.radians(skew)), 0.0])
        got = box_heading(points, guess, frames)
        assert math.degrees(math.acos(min(1.0, got @ R[:, 0]))) < 1.0
    # Pointing backwards snaps to the rear axis (the direction of travel decides, not the faces).
    got = box_heading(points, -R[:, 0] + 0.3 * R[:, 1], frames)
    assert got @ R[:, 0] < -0.99
    # Without vertical faces (a roof only), the direction of travel is kept.
    roof = np.stack([rng.uniform(-2, 2, 100), rng.uniform(-0.9, 0.9, 100), np.full(100, HEIGHT)], 1)
    guess = np.array([0.8, 0.6, 0.0])
    np.testing.assert_allclose(box_heading(roof, guess), guess, atol=1e-9)


def test_sparse_rear_views_leave_sideways_to_the_motion_and_dense_ones_keep_it():
    """``sparse_frame_points``: a far bus seen from behind in 30-70 points a frame slides sideways
    unchecked by any other frame; those frames leave across and up free. A followed car's dense
    rear views (80 points and more) keep the measured sigma there, as without the setting."""
    rng = np.random.default_rng(7)
    sigma, big = 0.2, 3.0
    counts = [30, 45, 60, 70, 120, 150]
    points = np.concatenate([rear(rng, n) for n in counts])
    frames = np.repeat(np.arange(len(counts)), counts)
    cov = translation_covariances(points, frames, len(counts), sigma, 0.2, big, sparse_frame_points=100)
    for f, n in enumerate(counts):
        expected = [sigma, big, big] if n < 100 else [sigma, sigma, sigma]  # along is what a rear measures
        np.testing.assert_allclose(np.sqrt(np.diag(cov[f])), expected, rtol=5e-3)
    np.testing.assert_allclose(translation_covariances(points, frames, len(counts), sigma, 0.2, big),
                               np.tile(np.eye(3) * sigma**2, (len(counts), 1, 1)), atol=1e-9)
    with pytest.raises(IDSplatError, match="sparse-frame-points"):
        SmoothingConfig(degenerate_sparse_frame_points=-1)
