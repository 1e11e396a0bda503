"""Instance tracks as JSON (data's own frame and clock): export, import, round trip, bad files;
idsplat-preprocess and ns-train share one stage cache."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.tracks_json import tracks_from_json, tracks_to_json, write_tracks_json
from idsplat_ns.nerfstudio.model_inputs import split_data


@pytest.fixture(scope="module")
def scene_and_tracks(tiny_street):
    from idsplat_ns.data.pandaset import load_sequence
    from idsplat_ns.instances.oracle import oracle_instance_tracks

    scene = load_sequence(tiny_street)
    tracks = oracle_instance_tracks(scene)
    assert len(tracks.instances) >= 1
    return scene, tracks


def test_export_is_in_the_datas_own_frame_and_clock(scene_and_tracks):
    scene, tracks = scene_and_tracks
    data = tracks_to_json(tracks, scene)
    inst, entry = tracks.instances[0], data["instances"][0]
    k = int(np.flatnonzero(inst.valid)[0])
    # The raw world is the recentred one shifted back: poses map through world_from_raw.
    assert np.allclose(scene.world_from_raw @ np.array(entry["poses"][0]), inst.poses[k], atol=1e-5)
    # The clock is the file's own: the lidar sweep's raw timestamp (seconds in the PandaSet layout).
    raw = json.loads((scene.root / "lidar" / "timestamps.json").read_text())
    frames = tracks.frame_indices[np.flatnonzero(inst.valid)]
    assert entry["times"] == pytest.approx([raw[int(f)] for f in frames], abs=1e-6)
    assert len(entry["times"]) == len(entry["poses"]) == len(entry["num_points"]) == inst.num_valid


def test_round_trip_restores_poses_validity_and_points(scene_and_tracks, tmp_path):
    scene, tracks = scene_and_tracks
    path = tmp_path / "tracks.json"
    write_tracks_json(path, tracks, scene)
    back = tracks_from_json(path, scene)
    assert [i.instance_id for i in back.instances] == [i.instance_id for i in tracks.instances]
    for a, b in zip(tracks.instances, back.instances):
        first, last = np.flatnonzero(a.valid)[[0, -1]]
        span = np.zeros_like(a.valid)
        span[first:last + 1] = True
        assert np.array_equal(b.valid, span)  # present over its time span
        assert np.allclose(b.poses[a.valid], a.poses[a.valid], atol=1e-5)
        assert np.allclose(b.canonical_points, a.canonical_points, atol=1e-4)
        assert np.array_equal(b.point_counts[a.valid], a.point_counts[a.valid])


def test_canonical_colours_survive_the_round_trip_and_are_optional(scene_and_tracks, tmp_path):
    # Self-supervised tracks carry each point's colour, which the instance Gaussians start from:
    # a re-imported file must give them back, and a file without them still imports (None:
    # colours are then projected from the images).
    from dataclasses import replace

    scene, tracks = scene_and_tracks
    rng = np.random.default_rng(0)
    coloured = replace(tracks, instances=[
        replace(i, canonical_colors=rng.integers(0, 256, (len(i.canonical_points), 3)).astype(np.uint8))
        for i in tracks.instances])  # fmt: skip
    write_tracks_json(tmp_path / "coloured.json", coloured, scene)
    back = tracks_from_json(tmp_path / "coloured.json", scene)
    for a, b in zip(coloured.instances, back.instances):
        assert b.canonical_colors.dtype == np.uint8 and np.array_equal(b.canonical_colors, a.canonical_colors)
    assert "canonical_colors" not in tracks_to_json(tracks, scene)["instances"][0]
    write_tracks_json(tmp_path / "plain.json", tracks, scene)
    assert all(i.canonical_colors is None for i in tracks_from_json(tmp_path / "plain.json", scene).instances)


def test_import_interpolates_between_times_and_finds_points_in_a_box(scene_and_tracks, tmp_path):
    scene, tracks = scene_and_tracks
    data = tracks_to_json(tracks, scene)
    inst = max(tracks.instances, key=lambda i: i.num_valid)
    entry = next(e for e in data["instances"] if e["id"] == inst.instance_id)
    assert len(entry["times"]) >= 3
    # Every other time only, no points: the middle ones must come back interpolated, points from the box.
    size = (inst.canonical_points.max(0) - inst.canonical_points.min(0)) + 0.4
    sparse = {"instances": [{"id": entry["id"], "times": entry["times"][::2], "poses": entry["poses"][::2],
                             "size": size.tolist()}]}
    path = tmp_path / "sparse.json"
    path.write_text(json.dumps(sparse))
    back = tracks_from_json(path, scene).instances[0]
    valid = np.flatnonzero(inst.valid)
    mid = valid[1]  # dropped from the file
    assert back.valid[mid]
    expected = 0.5 * (inst.poses[valid[0], :3, 3] + inst.poses[valid[2], :3, 3])
    assert np.allclose(back.poses[mid, :3, 3], expected, atol=1e-4)
    assert back.point_counts[valid[0]] >= 0.9 * inst.point_counts[valid[0]] > 0
    local = back.canonical_points
    assert np.all(np.abs(local) <= size / 2 + 1e-9)
    # The rotation halfway between its neighbours' (scipy's Slerp; the frames are evenly spaced).
    halfway = Slerp([0.0, 1.0], Rotation.from_matrix(inst.poses[[valid[0], valid[2]], :3, :3]))(0.5)
    assert np.allclose(back.poses[mid, :3, :3], halfway.as_matrix(), atol=1e-5)


@pytest.mark.parametrize("content, match", [
    ("not json", "not readable as JSON"),
    ('{"tracks": []}', "no 'instances' list"),
    ('{"instances": [{"id": 0, "times": [0], "poses": []}]}', "integer 'id' >= 1"),
    ('{"instances": [{"id": 1, "times": [0, 1], "poses": [[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]]}]}', "2 times and 1 poses"),
    ('{"instances": [{"id": 1, "times": [1, 0], "poses": [%s, %s], "size": [1, 1, 1]}]}' % ((str(np.eye(4).tolist()),) * 2), "increase strictly"),
    ('{"instances": [{"id": 1, "times": [0], "poses": [[1, 2]]}]}', "shape \\[N, 4, 4\\]"),
    # Named by its id, not its place in the list; by its place only when it has no usable id.
    ('{"instances": [{"id": 1, "times": [0], "poses": [%s], "size": [1, 1, 1]}, {"id": 7, "times": [0], "poses": [[1]]}]}'
     % str(np.eye(4).tolist()), "bad.json: instance id 7: 'poses' must be"),
    ('{"instances": [{"id": 1, "times": [0], "poses": [%s], "size": [1, 1, 1]}, {"id": "7"}]}' % str(np.eye(4).tolist()),
     "bad.json: instances\\[1\\]: needs an integer 'id'"),
    ('{"instances": [{"id": 1, "times": [0], "poses": [%s]}]}' % str(np.eye(4).tolist()), "canonical_points' or a box 'size'"),
    ('{"instances": [{"id": 1, "times": [0], "poses": [%s], "canonical_points": [[0, 0, 0], [1, 0, 0]], '
     '"canonical_colors": [[0, 0, 0]]}]}' % str(np.eye(4).tolist()), "one \\[r, g, b\\] in 0-255 per canonical point \\(2\\), got 1"),
    ('{"instances": [{"id": 1, "times": [0], "poses": [%s], "canonical_points": [[0, 0, 0]], '
     '"canonical_colors": [[0, 0, 300]]}]}' % str(np.eye(4).tolist()), "in 0-255"),
])
def test_bad_tracks_files_fail_in_one_line_naming_the_file(scene_and_tracks, tmp_path, content, match):
    scene, _ = scene_and_tracks
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(IDSplatError, match=match) as err:
        tracks_from_json(path, scene)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_preprocess_and_ns_train_share_one_cache(tiny_street, tmp_path, capsys):
    pytest.importorskip("nerfstudio")
    from idsplat_ns.nerfstudio.builtin_scene import instance_cache_dir
    from idsplat_ns.nerfstudio.dataparser import PandaSetDataParserConfig
    from idsplat_ns.cli.preprocess import PreprocessArgs, preprocess

    export = tmp_path / "t.json"
    tracks = preprocess(PreprocessArgs(data=tiny_street, export=export))
    assert export.is_file() and len(json.loads(export.read_text())["instances"]) == len(tracks.instances)
    cache = instance_cache_dir(tiny_street.name)
    assert any(cache.glob("registration-*.npz"))
    capsys.readouterr()
    # The datamanager's path: same scene, same training frames, same cache -> every stage from the cache.
    from idsplat_ns.instances.modes import instance_tracks_for_mode
    from idsplat_ns.instances.runner import PreprocessConfig

    outputs = PandaSetDataParserConfig(data=tiny_street).setup().get_dataparser_outputs("train")
    again = instance_tracks_for_mode(split_data(outputs.metadata).scene, "self-supervised", split_data(outputs.metadata).frames,
                                     PreprocessConfig(), cache)
    table = capsys.readouterr().out
    assert "registration" in table and "cache - registration" in table
    assert [i.instance_id for i in again.instances] == [i.instance_id for i in tracks.instances]
