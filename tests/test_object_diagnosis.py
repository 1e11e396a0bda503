"""The per-object diagnosis of ns-eval (eval/object_diagnosis.py): frames tracked and lost per
annotated moving object, lost stretches, frames lost near the ego, split objects, each object's
DPSNR; the per-object matches against motmetrics' own events; the moving objects' pixel map."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from _instances_fixtures import CAR_SIZE, make_scene
from idsplat_ns.data.dynamic_masks import moving_object_map
from idsplat_ns.data.geometry import make_pose
from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.data.tracks import ObjectTrack
from idsplat_ns.eval.object_diagnosis import NEAR_EGO, diagnose_objects, diagnosis_summary
from idsplat_ns.eval.object_plots import plot_object_timeline
from idsplat_ns.eval.tracking import clear_mot, object_matches
from idsplat_ns.eval.trajectory_eval import ObservedFilter

EVERY_FRAME = ObservedFilter(min_lidar_points=0)


def _close_car(num_frames: int) -> ObjectTrack:
    """A moving car 6-8 m ahead and left of the ego's lidar: near the ego, in the front camera."""
    poses = np.repeat(make_pose(np.eye(3), np.array([6.0, 2.0, CAR_SIZE[2] / 2]))[None], num_frames, 0)
    poses[:, 0, 3] += 0.3 * np.arange(num_frames)
    return ObjectTrack("close", "car", np.arange(num_frames), np.arange(num_frames) * 0.1, poses, CAR_SIZE, True)


@pytest.fixture()
def scene():
    base = make_scene(num_frames=10)
    return replace(base, tracks=list(base.tracks) + [_close_car(10)])


def _predictions(scene, lost: dict, renamed: dict = None):
    """Predictions at the annotated centres of the moving objects, except ``lost`` {track: frames};
    ``renamed`` {track: (from frame, new id)} splits a track into a second prediction ID."""
    renamed = renamed or {}

    def positions_at(t: float) -> dict:
        f = int(round(t / 0.1))
        out = {}
        for trk in scene.tracks:
            if trk.moving and f not in lost.get(trk.track_id, ()):
                start, new = renamed.get(trk.track_id, (None, None))
                out[new if start is not None and f >= start else trk.track_id] = trk.poses[f, :3, 3] + 0.1
        return out
    return positions_at


def test_every_frame_tracked_by_the_oracle(scene):
    records = diagnose_objects(scene, _predictions(scene, {}), observed=EVERY_FRAME)
    assert {r.track_id for r in records} == {"moving", "close"}  # the parked car is not an object here
    for r in records:
        assert len(r.frames) == 10 and all(r.tracked) and r.frames_lost == 0 and r.fragments == 1
        assert np.allclose(r.error, np.sqrt(3) * 0.1)
    close = next(r for r in records if r.track_id == "close")
    assert close.frames_near == sum(d < NEAR_EGO for d in close.distance_to_ego) > 0
    assert close.distance_to_ego[0] == pytest.approx(np.linalg.norm([6.0, 2.0, CAR_SIZE[2] / 2 - 1.9]))


def test_lost_frames_stretches_and_near_losses(scene):
    records = diagnose_objects(scene, _predictions(scene, {"close": {2, 3, 4, 5, 8}}), observed=EVERY_FRAME)
    close = next(r for r in records if r.track_id == "close")
    assert close.frames_lost == 5 and close.longest_lost == 4
    assert close.frames_lost_near == sum(d < NEAR_EGO for f, d in zip(close.frames, close.distance_to_ego)
                                         if f in {2, 3, 4, 5, 8})  # fmt: skip
    assert close.as_dict()["lost_frames"] == [2, 3, 4, 5, 8]
    assert records[0].track_id == "close"  # the worst vehicle first
    summary = diagnosis_summary(records)
    assert summary["objects_frames_lost"] == 5 and summary["objects_lost_over_3_frames"] == 1
    assert summary["objects_frames"] == 20


def test_a_split_track_has_two_fragments(scene):
    records = diagnose_objects(scene, _predictions(scene, {}, {"moving": (5, "second")}), observed=EVERY_FRAME)
    moving = next(r for r in records if r.track_id == "moving")
    assert moving.fragments == 2 and moving.frames_lost == 0
    assert diagnosis_summary(records)["objects_split"] == 1


def test_dpsnr_of_each_object_from_its_pixel_errors(scene):
    # 100 pixels with a squared error of 0.01 per channel: MSE 0.01, 20 dB.
    records = diagnose_objects(scene, _predictions(scene, {}), observed=EVERY_FRAME,
                               object_errors={"close": (100 * 3 * 0.01, 100), "unknown": (1.0, 10)})  # fmt: skip
    close = next(r for r in records if r.track_id == "close")
    assert close.dpsnr == pytest.approx(20.0) and close.pixels == 100
    assert next(r for r in records if r.track_id == "moving").dpsnr is None


def test_object_matches_agree_with_clear_mot():
    rng = np.random.default_rng(0)
    gt = {f: {k: rng.uniform(0, 20, 3) for k in range(4) if rng.random() < 0.8} for f in range(30)}
    pred = {f: {10 + k: xyz + rng.normal(0, 1.2, 3) for k, xyz in objs.items() if rng.random() < 0.8} for f, objs in gt.items()}
    for threshold in (1.0, 2.0):
        matches = object_matches(gt, pred, threshold)
        m = clear_mot(gt, pred, [threshold])[threshold]
        assert len(matches) == m.num_objects
        assert sum(v is None for v in matches.values()) == m.num_misses
        assert sum(v is not None for v in matches.values()) == m.num_matches + m.num_switches
        assert np.isclose(sum(v[1] for v in matches.values() if v is not None), m.total_distance)
        assert all(v is None or v[1] <= threshold for v in matches.values())


def test_timeline_plot(scene, tmp_path):
    records = diagnose_objects(scene, _predictions(scene, {"close": {3}}), observed=EVERY_FRAME)
    path = plot_object_timeline(records, tmp_path / "plots" / "objects.png", "test")
    assert path.is_file() and path.stat().st_size > 1000


def test_moving_object_map_of_the_builtin_street(tiny_street):
    scene = load_sequence(tiny_street)
    moving = {t.track_id for t in scene.tracks if t.moving}
    seen = set()
    for image in scene.images[:6]:
        index, ids = moving_object_map(scene, image, 1.0)
        assert index.shape == (image.intrinsics.height, image.intrinsics.width)
        assert set(ids) <= moving and index.max() < len(ids)
        assert all((index == k).any() for k in range(len(ids)))  # every listed object has pixels
        seen |= set(ids)
    assert seen
    # Without the dataset's masks the boxes' silhouettes are drawn: the same objects, nearly the same pixels.
    image = scene.images[3]
    masked, ids = moving_object_map(scene, image, 1.0)
    boxes, box_ids = moving_object_map(replace(scene, metadata={}), image, 1.0)
    annotated = {t.track_id for t in scene.tracks if t.index_of_frame(image.frame_index) is not None}
    assert set(ids) & annotated and set(ids) & annotated <= set(box_ids)  # boxes beyond 100 m are not annotated
    agree = total = 0
    for k, tid in enumerate(ids):
        if tid not in annotated:
            continue
        inside = boxes[masked == k]
        assert (inside >= 0).mean() > 0.9  # its pixels lie in the silhouettes
        agree, total = agree + (inside == box_ids.index(tid)).sum(), total + inside.size
    # Mostly the same object: overlapping boxes are ordered by their centres' distance, which a
    # long vehicle's near end can contradict.
    assert agree / total > 0.6


def test_along_error_is_the_part_of_the_error_along_the_heading(scene):
    """Predictions 0.3 m ahead in world x and 0.4 m in world y of every moving object: the close
    car heads along world x (0.3 m of its 0.5 m error lie along it), a turned car splits the same
    offset by its yaw."""
    turned = replace(scene.tracks[-1], track_id="turned", poses=scene.tracks[-1].poses.copy())
    yaw = np.radians(30.0)
    turned.poses[:, :3, :3] = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    turned.poses[:, 1, 3] += 6.0  # beside the close car, not on it
    scene = replace(scene, tracks=list(scene.tracks) + [turned])
    offset = np.array([0.3, 0.4, 0.0])

    def positions_at(t: float) -> dict:
        f = int(round(t / 0.1))
        return {trk.track_id: trk.poses[f, :3, 3] + offset for trk in scene.tracks if trk.moving}

    records = {r.track_id: r for r in diagnose_objects(scene, positions_at, observed=EVERY_FRAME)}
    assert np.allclose(records["close"].error, 0.5) and np.allclose(records["close"].along_error, 0.3)
    assert np.allclose(records["turned"].along_error, 0.3 * np.cos(yaw) + 0.4 * np.sin(yaw))
    assert records["close"].as_dict()["mean_along_error"] == pytest.approx(0.3)
    lost = diagnose_objects(scene, _predictions(scene, {"close": {2}}), observed=EVERY_FRAME)
    assert np.isnan(next(r for r in lost if r.track_id == "close").along_error[2])
