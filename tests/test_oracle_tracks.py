"""Oracle instance tracks (ground-truth boxes, the SplatAD-style upper bound) on the tiny synthetic street."""

from __future__ import annotations

import numpy as np
import pytest

from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.instances.oracle import oracle_instance_tracks
from idsplat_ns.instances.tracks import InstanceTracks


@pytest.fixture(scope="module")
def scene(tiny_street):
    return load_sequence(tiny_street)


def test_oracle_tracks_match_ground_truth(scene, tmp_path):
    tracks = oracle_instance_tracks(scene)
    moving = [t for t in scene.tracks if t.moving]
    assert len(moving) >= 3 and len(tracks.instances) >= 3
    assert [i.instance_id for i in tracks.instances] == list(range(1, len(tracks.instances) + 1))
    assert np.array_equal(tracks.frame_indices, scene.frame_indices)
    by_id = {t.track_id: t for t in scene.tracks}
    for inst in tracks.instances:
        gt = by_id[tracks.metadata["track_ids"][str(inst.instance_id)]]
        assert gt.moving and inst.label == gt.label
        # Poses equal the ground-truth box poses where annotated, and only there are they valid.
        rows = np.searchsorted(scene.frame_indices, gt.frame_indices)
        assert np.array_equal(np.flatnonzero(inst.valid), rows)
        assert np.allclose(inst.poses[rows], gt.poses, atol=1e-12)
        # Canonical points lie in the box (box frame: centred, x along the length).
        half = np.asarray(gt.size) / 2
        assert np.all(np.abs(inst.canonical_points) <= half + 0.05 + 1e-9)
        assert inst.canonical_points[:, 2].min() >= -half[2] + 0.05 - 1e-9  # road under the box left out
        assert len(inst.canonical_points) >= 10 and inst.point_counts.sum() >= len(inst.canonical_points)
        assert inst.valid[inst.canonical_frame]
    # A well-observed car fills its box: the points span most of its length and width.
    car = max(tracks.instances, key=lambda i: len(i.canonical_points))
    size = np.asarray(by_id[tracks.metadata["track_ids"][str(car.instance_id)]].size)
    extent = car.canonical_points.max(0) - car.canonical_points.min(0)
    assert np.all(extent[:2] > 0.8 * size[:2])
    # The result is an ordinary InstanceTracks: it saves and loads.
    tracks.save(tmp_path / "oracle.npz")
    back = InstanceTracks.load(tmp_path / "oracle.npz")
    assert [i.instance_id for i in back.instances] == [i.instance_id for i in tracks.instances]


def test_oracle_frames_restrict_points_not_poses(scene):
    train = set(scene.frame_indices[:5].tolist())
    full_tracks = oracle_instance_tracks(scene)
    part = oracle_instance_tracks(scene, frames=train, min_points=1)
    gt_id = lambda tr, inst: tr.metadata["track_ids"][str(inst.instance_id)]
    full = {gt_id(full_tracks, i): i for i in full_tracks.instances}
    matched = 0
    for inst in part.instances:
        assert np.all(inst.point_counts[5:] == 0)
        ref = full.get(gt_id(part, inst))
        if ref is not None:
            matched += 1
            assert np.array_equal(inst.valid, ref.valid)  # poses cover every annotated frame
            assert np.allclose(inst.poses[inst.valid], ref.poses[ref.valid])
    assert matched >= 3
    assert sum(len(i.canonical_points) for i in part.instances) < sum(len(i.canonical_points) for i in full_tracks.instances)


def test_oracle_moving_only_and_min_points(scene):
    all_tracks = oracle_instance_tracks(scene, moving_only=False)
    moving = oracle_instance_tracks(scene)
    assert len(all_tracks.instances) > len(moving.instances)
    assert len(oracle_instance_tracks(scene, min_points=10**7).instances) == 0
