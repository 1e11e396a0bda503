"""Masks -> lidar lifting, the mask folder format, oracle masks, trajectory estimation, static
conversion and the pose-error measure (eval/instance_pose_errors.py) on a hand-built scene."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage

from _instances_fixtures import CAR_SIZE, body_features, box_surface, make_scene
from idsplat_ns.data.geometry import invert_pose, make_pose, rot_z, transform_points
from idsplat_ns.data.tracks import points_in_box
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.lifting import LiftingConfig, erode_instance_map, erode_instance_map_adaptive, lift_instances
from idsplat_ns.instances.masks.base import write_instance_map, write_labels
from idsplat_ns.instances.masks.gt_boxes import GtBoxMasksConfig, GtBoxMaskSource
from idsplat_ns.instances.masks.precomputed import PrecomputedMasksConfig, PrecomputedMaskSource, load_mask_set
from idsplat_ns.instances.registration import RegistrationConfig
from idsplat_ns.instances.static_conversion import convert_static_instances
from idsplat_ns.eval.instance_pose_errors import summarise_errors
from idsplat_ns.instances.trajectory_config import TrajectoryConfig
from idsplat_ns.instances.trajectory_estimation import estimate_trajectories
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks


@pytest.fixture(scope="module")
def scene():
    return make_scene()


@pytest.fixture(scope="module")
def oracle_masks(scene, tmp_path_factory):
    return GtBoxMaskSource(GtBoxMasksConfig()).generate(scene, tmp_path_factory.mktemp("oracle"), progress=False)


def test_erosion_matches_per_instance_binary_erosion():
    rng = np.random.default_rng(0)
    ids = np.zeros((60, 80), np.uint16)
    ids[10:40, 5:30] = 1
    ids[20:50, 30:70] = 2  # touches instance 1
    ids[rng.random(ids.shape) < 0.01] = 3
    out = erode_instance_map(ids, 3)
    import cv2

    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)).astype(bool)
    for k in (1, 2, 3):
        # reference: binary erosion of each instance alone (pixels next to another instance go too)
        ref = ndimage.binary_erosion(ids == k, structure=disk, border_value=1)
        np.testing.assert_array_equal(out == k, ref)
    assert (out == 3).sum() == 0 and (out == 1).sum() < (ids == 1).sum()


def test_adaptive_erosion_trims_large_masks_and_keeps_small_ones():
    ids = np.zeros((60, 80), np.uint16)
    ids[5:45, 5:40] = 1  # large: the full radius keeps most of it
    ids[50:54, 10:70] = 2  # 4 px tall, like a far bus: one pixel of erosion removes half of it
    ids[20:28, 50:58] = 3  # 8x8: radius 3 leaves 4 of 64 pixels, radius 1 leaves 36
    out = erode_instance_map_adaptive(ids, 3, 0.5)
    np.testing.assert_array_equal(out == 1, erode_instance_map(ids, 3) == 1)
    np.testing.assert_array_equal(out == 2, ids == 2)  # kept whole
    np.testing.assert_array_equal(out == 3, erode_instance_map(ids, 1) == 3)
    assert set(np.unique(out)) == {0, 1, 2, 3}
    # 0 (or radius 0) is the paper's fixed erosion
    np.testing.assert_array_equal(erode_instance_map_adaptive(ids, 3, 0.0), erode_instance_map(ids, 3))
    np.testing.assert_array_equal(erode_instance_map_adaptive(ids, 0, 0.5), ids)


def test_oracle_masks_cover_projected_boxes(scene, oracle_masks):
    ids = oracle_masks.load("front_camera", 0)
    assert ids.dtype == np.uint16 and ids.shape == (200, 320)
    assert set(np.unique(ids)) == {0, 1, 2}
    # the centre of the moving car projects inside its mask
    uv = scene.images[0].project(scene.tracks[0].poses[0][None, :3, 3]).uv[0]
    assert ids[int(uv[1]), int(uv[0])] == 1
    assert oracle_masks.labels == {1: "car", 2: "car"}


def _fraction_in_box(scene, lifted, iid, track):
    fr = []
    for o in lifted.observations[iid]:
        fr.append(points_in_box(o.points, scene.tracks[track].poses[o.frame], CAR_SIZE, margin=0.05).mean())
    return np.array(fr)


def test_lifting_keeps_object_points_and_filters_background(scene, oracle_masks):
    lifted = lift_instances(scene, oracle_masks, LiftingConfig(), progress=False)
    assert sorted(lifted.observations) == [1, 2]
    assert [o.frame for o in lifted.observations[1]] == list(range(6))
    assert np.all(_fraction_in_box(scene, lifted, 1, 0) > 0.99)
    assert np.all(_fraction_in_box(scene, lifted, 2, 1) > 0.99)
    o = lifted.observations[1][0]
    assert len(o.points) > 200 and o.uv.shape == (len(o.points), 2)
    # each point carries its own ray's time (the sweep's time of that very point)
    sweep = next(s for s in scene.lidar if s.frame_index == scene.frame_indices[o.frame])
    ray_time = dict(zip(map(tuple, sweep.points), sweep.times[sweep.returned]))
    assert o.times.shape == (len(o.points),)
    np.testing.assert_array_equal(o.times, [ray_time[tuple(p)] for p in o.points])
    # no erosion and no DBSCAN: the box silhouette also catches ground and wall points
    raw = lift_instances(scene, oracle_masks, LiftingConfig(erosion_px=0, use_dbscan=False), progress=False)
    assert np.mean(_fraction_in_box(scene, raw, 1, 0)) < np.mean(_fraction_in_box(scene, lifted, 1, 0)) - 0.02
    # points beyond 80 m never enter
    far = lift_instances(scene, oracle_masks, LiftingConfig(max_distance=15.0), progress=False)
    assert all(np.linalg.norm(o.points - [0, 0, 1.9], axis=1).max() <= 15.0 for obs in far.observations.values() for o in obs)


def test_cross_camera_ids_are_merged(scene, oracle_masks, tmp_path):
    # Rewrite the oracle masks with a different ID for the moving car in the left camera.
    for im in scene.images:
        ids = oracle_masks.load(im.camera, im.frame_index)
        if im.camera == "front_left_camera":
            ids = np.where(ids == 1, 7, ids).astype(np.uint16)
        write_instance_map(tmp_path / im.camera / f"{im.frame_index:02d}.png", ids)
    write_labels(tmp_path, {1: "car", 2: "car", 7: "car"})
    lifted = lift_instances(scene, load_mask_set(tmp_path), LiftingConfig(), progress=False)
    seen_left = any((im.camera == "front_left_camera") and (oracle_masks.load(im.camera, im.frame_index) == 1).any()
                    for im in scene.images)
    assert seen_left
    assert sorted(lifted.observations) == [1, 2]


def test_precomputed_format_and_errors(scene, oracle_masks, tmp_path):
    src = PrecomputedMaskSource(PrecomputedMasksConfig(mask_dir=oracle_masks.root))
    masks = src.generate(scene, tmp_path, progress=False)
    np.testing.assert_array_equal(masks.load("front_camera", 3), oracle_masks.load("front_camera", 3))
    assert masks.load("front_camera", 99) is None  # a missing PNG is a missed frame
    with pytest.raises(IDSplatError, match="instances.json"):
        load_mask_set(tmp_path)
    (tmp_path / "instances.json").write_text(json.dumps({"1": {"name": "car"}}))
    with pytest.raises(IDSplatError, match="malformed"):
        load_mask_set(tmp_path)
    with pytest.raises(IDSplatError, match="mask-dir"):
        PrecomputedMaskSource(PrecomputedMasksConfig())
    (tmp_path / "front_camera").mkdir()
    import cv2

    cv2.imwrite(str(tmp_path / "front_camera" / "00.png"), np.zeros((4, 4, 3), np.uint8))
    (tmp_path / "instances.json").write_text(json.dumps({"1": {"label": "Car"}}))
    bad = load_mask_set(tmp_path)
    assert bad.labels == {1: "car"}
    with pytest.raises(IDSplatError, match="uint16"):
        bad.load("front_camera", 0)


def _oracle_features(scene, lifted) -> PointFeatures:
    """Features that are a function of the body-frame position (perfect descriptors)."""
    feats = {}
    for iid, obs in lifted.observations.items():
        track = scene.tracks[iid - 1]
        for o in obs:
            local = transform_points(invert_pose(track.poses[o.frame]), o.points)
            feats[(iid, o.frame)] = body_features(local)
    return PointFeatures("oracle", feats, {})


def test_registration_trajectories_and_static_conversion(scene, oracle_masks, tmp_path):
    lifted = lift_instances(scene, oracle_masks, LiftingConfig(), progress=False)
    cfg = TrajectoryConfig(registration=RegistrationConfig(max_iterations=3000, similarity_threshold=0.9))
    tracks = estimate_trajectories(scene, lifted, _oracle_features(scene, lifted), cfg, progress=False)
    moving = tracks.instance(1)
    assert moving.valid.all()
    summary = summarise_errors(scene, tracks, min_points=50)
    assert summary.matched_tracks == 1 and summary.frames_evaluated == 5
    assert summary.median_translation < 0.05 and summary.median_rotation_deg < 0.5
    # canonical frame: identity rotation, origin at the box centre of the densest frame
    c = moving.canonical_frame
    assert moving.point_counts[c] == moving.point_counts.max()
    np.testing.assert_allclose(moving.poses[c][:3, :3], np.eye(3))
    # each canonical point keeps the ray time of the lidar point it came from
    for o in lifted.observations[1]:
        np.testing.assert_array_equal(moving.point_times[moving.point_frames == o.frame], o.times)
    # the parked car does not move: it becomes static
    converted = convert_static_instances(tracks)
    assert [i.instance_id for i in converted.instances] == [1]
    assert [i.instance_id for i in converted.static_instances] == [2]
    # round trip through the file format
    converted.save(tmp_path / "t.npz")
    back = InstanceTracks.load(tmp_path / "t.npz")
    np.testing.assert_allclose(back.instance(1).poses, moving.poses)
    np.testing.assert_array_equal(back.instance(1).point_times, moving.point_times)
    assert back.static_instances[0].instance_id == 2


def test_centroid_ablation_is_worse_than_registration(scene, oracle_masks):
    lifted = lift_instances(scene, oracle_masks, LiftingConfig(), progress=False)
    tracks = estimate_trajectories(scene, lifted, None, TrajectoryConfig(method="centroid"), progress=False)
    summary = summarise_errors(scene, tracks, min_points=50)
    # centroids move with the visible part of the car and ignore the turn
    assert summary.median_rotation_deg > 1.0


def test_pose_errors_of_hand_placed_estimates(scene):
    """The error measure the tests above rely on, on estimates with known errors: the canonical
    origin sits 0.8 m ahead and 0.3 m left of the box centre (a pure offset g), frame 2 is 0.3 m
    off in the world, frame 4 turned 5 degrees about the canonical origin, frame 5 2 m off but
    with only 10 points; the parked car's exact instance is not a moving vehicle."""
    moving, parked = scene.tracks
    g = make_pose(np.eye(3), np.array([0.8, 0.3, 0.0]))  # canonical -> box
    body = box_surface(500, CAR_SIZE, np.random.default_rng(0))
    poses = moving.poses @ g  # canonical -> world, exact
    poses[2] = make_pose(np.eye(3), np.array([0.0, 0.3, 0.0])) @ poses[2]
    poses[4] = poses[4] @ make_pose(rot_z(np.radians(5.0)), np.zeros(3))
    poses[5] = make_pose(np.eye(3), np.array([2.0, 0.0, 0.0])) @ poses[5]
    counts = np.array([100, 100, 100, 100, 100, 10])
    inst = InstanceTrack(4, "car", body - g[:3, 3], None, poses, np.ones(6, bool), counts, np.ones(6), 0)
    still = InstanceTrack(5, "car", body, None, parked.poses.copy(), np.ones(6, bool), counts, np.ones(6), 0)
    summary = summarise_errors(scene, InstanceTracks(np.arange(6), scene.frame_times, [inst], [still]), min_points=50)
    (errors,) = summary.per_instance
    assert errors.instance_id == 4 and errors.track_index == 0 and errors.frames.tolist() == [1, 2, 3, 4, 5]
    # Turning 5 degrees about a point |g| from the box centre moves the centre by the chord 2 |g| sin(2.5°).
    chord = 2 * np.hypot(0.8, 0.3) * np.sin(np.radians(2.5))
    np.testing.assert_allclose(errors.translation, [0.0, 0.3, 0.0, chord, 2.0], atol=1e-9)
    np.testing.assert_allclose(errors.rotation_deg, [0.0, 0.0, 0.0, 5.0, 0.0], atol=1e-6)
    # Frame 5 has too few points for the medians: over frames 1-4 they are (0 + chord) / 2 and 0.
    assert summary.frames_evaluated == 4 and summary.median_translation == pytest.approx(chord / 2)
    assert summary.median_rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert summary.median_translation_instances == pytest.approx(chord)  # all 5 frames of a 100-point instance
    assert (summary.matched_tracks, summary.moving_vehicle_tracks) == (1, 1)
