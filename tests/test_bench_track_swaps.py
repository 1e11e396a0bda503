"""bench/bench_track_swaps.py's swap of a track's motion for the annotated box's: an instance that
already moves as its box is unchanged; a wrong pose is replaced by the box's motion; the whole span
covers every frame of the box and keeps one piece per object."""

from __future__ import annotations

import copy

import numpy as np

from bench.bench_track_swaps import with_true_motion
from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.instances.oracle import oracle_instance_tracks


def test_true_motion_replaces_poses_and_spans(tiny_street) -> None:
    scene = load_sequence(tiny_street)
    tracks = oracle_instance_tracks(scene)
    moving = [i for i in tracks.instances if i.valid.sum() >= 3]
    assert moving
    same = with_true_motion(tracks, scene, whole_span=False)
    for a, b in zip(tracks.instances, same.instances):
        assert np.allclose(a.poses[a.valid], b.poses[a.valid], atol=1e-9)
        assert np.array_equal(a.valid, b.valid)
    broken = copy.deepcopy(tracks)
    inst = next(i for i in broken.instances if i.instance_id == moving[0].instance_id)
    k = [f for f in np.flatnonzero(inst.valid) if f != inst.canonical_frame][0]
    inst.poses[k] = inst.poses[k] @ make_pose(rot_z(0.3), np.array([1.0, 0.5, 0.0]))  # a bad registration
    cut = np.flatnonzero(inst.valid)[-1]
    inst.valid[cut] = False  # and the last frame lost
    fixed = with_true_motion(broken, scene, whole_span=False)
    again = next(i for i in fixed.instances if i.instance_id == inst.instance_id)
    original = next(i for i in tracks.instances if i.instance_id == inst.instance_id)
    assert np.allclose(again.poses[k], original.poses[k], atol=1e-9)
    assert not again.valid[cut]
    spans = with_true_motion(broken, scene, whole_span=True)
    whole = next(i for i in spans.instances if i.instance_id == inst.instance_id)
    assert whole.valid[cut] and np.allclose(whole.poses[cut], original.poses[cut], atol=1e-9)
    split = copy.deepcopy(broken)
    piece = copy.deepcopy(inst)  # a second, smaller piece of the same object
    piece.instance_id, piece.canonical_points = 999, inst.canonical_points[: len(inst.canonical_points) // 2]
    split.instances.append(piece)
    assert 999 in [i.instance_id for i in with_true_motion(split, scene, whole_span=False).instances]
    assert 999 not in [i.instance_id for i in with_true_motion(split, scene, whole_span=True).instances]
