"""Smoother priors from the instance's own points: the direction of travel along the box axis
(heading prior) and the cap on a registration's vertical freedom."""

from __future__ import annotations

import math

import numpy as np
import pytest

from idsplat_ns.data.geometry import rot_z
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.smoothing.instance_tracks import instance_heading
from idsplat_ns.instances.smoothing import SmoothingConfig, smooth_trajectory
from idsplat_ns.instances.smoothing.observability import cap_vertical_variance, translation_covariances
from idsplat_ns.instances.smoothing.smoother import heading_yaw_near
from idsplat_ns.instances.tracks import InstanceTrack

from test_smoothing_observability import HEIGHT, LENGTH, WIDTH, front, side


def _roof(rng: np.random.Generator, n: int) -> np.ndarray:  # -> [n, 3]
    return np.stack([rng.uniform(-LENGTH / 2, LENGTH / 2, n), rng.uniform(-WIDTH / 2, WIDTH / 2, n),
                     np.full(n, HEIGHT) + rng.normal(0, 0.005, n)], 1)


def test_cap_vertical_variance_matches_adding_information_along_z():
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    cov = q @ np.diag([0.04, 2.0, 9.0]) @ q.T
    capped = cap_vertical_variance(cov, 0.3)
    assert capped[2, 2] == pytest.approx(0.09, rel=1e-9)
    # Independent reference: invert, add the information along z that leaves 0.09, invert back.
    a = 1.0 / 0.09 - 1.0 / cov[2, 2]
    reference = np.linalg.inv(np.linalg.inv(cov) + a * np.diag([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(capped, reference, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(capped) > 0)
    tight = np.diag([9.0, 0.04, 0.04])
    np.testing.assert_array_equal(cap_vertical_variance(tight, 0.3), tight)  # already within: unchanged


def test_side_views_free_up_and_along_are_capped_vertically_only():
    """Frames 0-2 see the side only; 3-5 side, front and roof (they anchor along and up). The
    side frames are free along the car and up; the cap keeps them within 0.3 m vertically."""
    rng = np.random.default_rng(1)
    chunks = [side(rng, 60) for _ in range(3)] + [
        np.concatenate([side(rng, 80), front(rng, 60), _roof(rng, 60)]) for _ in range(3)]
    points, frames = np.concatenate(chunks), np.repeat(np.arange(6), [len(c) for c in chunks])
    free = translation_covariances(points, frames, 6, 0.2, 0.2, 3.0)
    capped = translation_covariances(points, frames, 6, 0.2, 0.2, 3.0, vertical_sigma=0.3)
    for f in range(3):
        assert np.sqrt(np.diag(free[f])) == pytest.approx([3.0, 0.2, 3.0], rel=0.02)
        assert np.sqrt(np.diag(capped[f])) == pytest.approx([3.0, 0.2, 0.3], rel=0.02)
    np.testing.assert_allclose(capped[3:], free[3:], atol=1e-12)  # measured frames are untouched


def _crabbing_registrations(crab_deg: float = 4.0, steps: int = 12):
    """A vehicle driving straight at 8 m/s along yaw 0.3 rad whose registrations drift sideways
    (the far bus of the synthetic street: its rear face measures neither across nor up) so that
    they travel ``crab_deg`` off its axis. Returns times, truth, measurements, box axis (canonical)."""
    yaw, speed, dt = 0.3, 8.0, 0.1
    times = np.arange(steps) * dt
    axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    across = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    truth = np.tile(np.eye(4), (steps, 1, 1))
    truth[:, :3, :3] = rot_z(yaw)
    truth[:, :3, 3] = np.array([20.0, 5.0, 0.0]) + np.outer(speed * times, axis)
    measured = truth.copy()
    drift = math.tan(math.radians(crab_deg)) * speed * (times - times.mean())
    measured[:, :3, 3] += np.outer(drift, across)
    return times, truth, measured, np.array([1.0, 0.0, 0.0])  # canonical frame = the box at yaw 0.3


def test_heading_prior_keeps_a_crabbing_track_along_the_box_axis():
    """Without the prior the direction of travel follows the registrations' sideways drift (the
    vehicle drives 4 degrees off its own axis); with it, travel stays within 1 degree of the axis."""
    times, truth, measured, axis = _crabbing_registrations()
    valid = np.ones(len(times), bool)
    config = SmoothingConfig()
    plain = smooth_trajectory(times, measured, valid, config)
    prior = smooth_trajectory(times, measured, valid, config, heading=axis)

    def off_axis_deg(sm) -> float:
        x = sm.shared_rotation[:, 0]
        return abs(math.degrees(math.atan2(x[1], x[0])))

    assert off_axis_deg(plain) > 3.0
    assert off_axis_deg(prior) < 1.0
    # The track itself: each pose's forward axis against the truth (no crab: yaw exact).
    yaw_err = lambda sm: np.degrees(np.abs(np.arctan2(sm.poses[:, 1, 0], sm.poses[:, 0, 0]) - 0.3))
    assert yaw_err(prior).max() < 1.0


def test_heading_axis_is_flipped_towards_the_travel_direction_and_checked():
    shared = rot_z(0.2)
    assert heading_yaw_near(np.array([1.0, 0.0, 0.0]), shared) == pytest.approx(0.0)
    assert heading_yaw_near(np.array([-1.0, 0.0, 0.0]), shared) == pytest.approx(0.0, abs=1e-12)  # the other end
    assert heading_yaw_near(np.array([0.0, -1.0, 0.0]), rot_z(-1.4)) == pytest.approx(-0.5 * math.pi)
    assert heading_yaw_near(np.array([0.0, -1.0, 0.0]), rot_z(1.4)) == pytest.approx(0.5 * math.pi)
    with pytest.raises(IDSplatError, match="heading-prior-sigma"):
        SmoothingConfig(heading_prior_sigma=0.0)
    with pytest.raises(IDSplatError, match="degenerate-vertical-sigma"):
        SmoothingConfig(degenerate_vertical_sigma=-1.0)


def _instance(points: np.ndarray, frames: np.ndarray, steps: int = 6) -> InstanceTrack:
    poses = np.tile(np.eye(4), (steps, 1, 1))
    poses[:, 0, 3] = 1.5 * np.arange(steps)  # travels along canonical x
    return InstanceTrack(
        instance_id=1, label="car", canonical_points=points, canonical_colors=None, poses=poses,
        valid=np.ones(steps, bool), point_counts=np.bincount(frames, minlength=steps), fitness=np.ones(steps),
        canonical_frame=0, point_frames=frames)


def test_instance_heading_needs_enough_points():
    rng = np.random.default_rng(3)
    skew = rot_z(math.radians(5.0))[:3, :3]  # the box is turned 5 degrees from the travel direction
    chunks = [np.concatenate([side(rng, 40), front(rng, 30)]) @ skew.T for _ in range(6)]
    points, frames = np.concatenate(chunks), np.repeat(np.arange(6), [len(c) for c in chunks])
    min_points = SmoothingConfig().heading_prior_min_points  # 100
    heading = instance_heading(_instance(points, frames), min_points)
    assert math.degrees(math.atan2(heading[1], heading[0])) == pytest.approx(5.0, abs=0.5)
    few = frames < 1  # 70 points
    assert instance_heading(_instance(points[few], frames[few]), min_points) is None
