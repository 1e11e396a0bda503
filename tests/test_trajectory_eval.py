"""The tracking protocols of eval/trajectory_eval.py: which annotated objects count (camera view,
lidar range, lidar points), "don't care" predictions, the all-objects protocol, and the aligned
trajectory RMSE."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from _instances_fixtures import CAR_SIZE, make_scene
from idsplat_ns.data.geometry import make_pose
from idsplat_ns.data.tracks import ObjectTrack
from idsplat_ns.eval.trajectory_eval import (
    ObservedFilter, aligned_position_rmse, ground_truth_positions, tracking_summary,
)  # fmt: skip


def _with_tracks(scene, *extra):
    return replace(scene, tracks=list(scene.tracks) + list(extra))


def _moving_at(track_id: str, xyz, num_frames: int, dt: float = 0.1) -> ObjectTrack:
    poses = np.repeat(make_pose(np.eye(3), np.asarray(xyz, float))[None], num_frames, 0)
    poses[:, 0, 3] += 0.5 * np.arange(num_frames)  # it moves
    return ObjectTrack(track_id, "car", np.arange(num_frames), np.arange(num_frames) * dt, poses, CAR_SIZE, True)


def _oracle(scene, ids=None):
    """Predictions at the annotated centres of the moving vehicles (optionally only ``ids``)."""
    def positions_at(t: float) -> dict:
        f = int(round(t / 0.1))
        return {trk.track_id: trk.poses[f, :3, 3] for trk in scene.tracks
                if trk.moving and (ids is None or trk.track_id in ids)}
    return positions_at


def test_behind_the_cameras_does_not_count_and_is_dont_care():
    scene = make_scene()
    behind = _moving_at("behind", (-15.0, 0.0, 0.75), scene.num_frames)  # no camera looks backwards
    scene = _with_tracks(scene, behind)
    observed = ground_truth_positions(scene, observed=ObservedFilter(min_lidar_points=0))
    every = ground_truth_positions(scene)
    assert all("behind" not in objs and "moving" in objs for objs in observed.values())
    assert all("behind" in objs for objs in every.values())
    # a prediction on it is neither a match nor a false positive under the observed protocol
    m = tracking_summary(scene, _oracle(scene), observed=ObservedFilter(min_lidar_points=0))[2.0]
    assert m.num_objects == scene.num_frames and m.num_false_positives == 0 and m.mota == 1.0
    # not predicting it costs nothing there, but is a miss under the all-objects protocol
    m = tracking_summary(scene, _oracle(scene, {"moving"}), observed=ObservedFilter(min_lidar_points=0))[2.0]
    assert m.mota == 1.0
    m_all = tracking_summary(scene, _oracle(scene, {"moving"}), observed=None)[2.0]
    assert m_all.num_objects == 2 * scene.num_frames and m_all.num_misses == scene.num_frames
    assert np.isclose(m_all.mota, 0.5)


def test_range_and_lidar_point_filters():
    scene = make_scene()
    far = _moving_at("far", (90.0, 0.0, 1.0), scene.num_frames)  # in view, beyond 80 m
    unseen = _moving_at("unseen", (30.0, 16.5, 0.75), scene.num_frames)  # in view, beside the lidar points
    scene = _with_tracks(scene, far, unseen)
    default = ground_truth_positions(scene, observed=ObservedFilter())
    assert all(set(objs) == {"moving"} for objs in default.values())
    wide = ground_truth_positions(scene, observed=ObservedFilter(max_range=200.0, min_lidar_points=0))
    assert all(set(objs) == {"moving", "far", "unseen"} for objs in wide.values())
    # the real moving car carries far more than 10 points: the point filter keeps it
    assert all("moving" in objs for objs in ground_truth_positions(scene, observed=ObservedFilter(min_lidar_points=50)).values())


def test_a_wrong_prediction_elsewhere_is_still_a_false_positive():
    scene = make_scene()

    def positions_at(t: float) -> dict:
        out = _oracle(scene)(t)
        out["ghost"] = np.array([25.0, -12.0, 0.75])  # nowhere near any annotated object
        return out

    m = tracking_summary(scene, positions_at)[2.0]
    assert m.num_false_positives == scene.num_frames and np.isclose(m.mota, 0.0)


def test_aligned_position_rmse_by_hand_and_against_least_squares():
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    # Two frames, same orientation, the boxes 0.25 m ahead of and behind where a fixed canonical
    # point puts them: the best point is the middle one, and 0.25 m remains at both frames.
    poses = np.stack([make_pose(np.eye(3), np.array([k * 3.0, 1.0, 0.0])) for k in range(2)])
    centre = np.array([1.2, -0.4, 0.3])  # the box centre in the canonical frame
    gt = poses[:, :3, 3] + centre + np.array([[0.25, 0.0, 0.0], [-0.25, 0.0, 0.0]])
    assert aligned_position_rmse(poses, gt) == pytest.approx(0.25)
    # A turning, climbing trajectory: exact boxes give 0 whatever the canonical origin; noisy ones
    # the residual of the least-squares canonical point, found here numerically.
    rng = np.random.default_rng(0)
    R = Rotation.from_euler("zyx", np.c_[np.linspace(0, 1.5, 12), rng.normal(0, 0.05, (12, 2))]).as_matrix()
    poses = make_pose(R, rng.normal(0, 5.0, (12, 3)))
    exact = np.einsum("tij,j->ti", R, centre) + poses[:, :3, 3]
    assert aligned_position_rmse(poses, exact) == pytest.approx(0.0, abs=1e-12)
    noisy = exact + rng.normal(0, 0.2, exact.shape)
    fit = least_squares(lambda c: (np.einsum("tij,j->ti", R, c) + poses[:, :3, 3] - noisy).ravel(), np.zeros(3))
    expected = np.sqrt(np.mean(np.sum(fit.fun.reshape(-1, 3) ** 2, axis=1)))
    assert aligned_position_rmse(poses, noisy) == pytest.approx(expected, rel=1e-6)
