"""Instance editing (issue 21): removal, moves, re-timing and duplication change the rendered
instance masks as they should, and an edited run written by idsplat-edit loads like any run."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest
import torch

pytest.importorskip("nerfstudio")

from _tiny_run import loaded_pipeline, tiny_run  # noqa: E402

from idsplat_ns.data.tracks import label_group  # noqa: E402
from idsplat_ns.model.editing import EditError, SceneTensors  # noqa: E402
from idsplat_ns.nerfstudio.camera_read import read_camera  # noqa: E402
from idsplat_ns.nerfstudio.model_inputs import instance_inputs

PREFIX = "_model.scene_model."


@pytest.fixture(scope="module")
def run_config(tiny_street, tmp_path_factory):
    return tiny_run(tiny_street, tmp_path_factory)


@pytest.fixture(scope="module")
def pipeline(run_config):
    pipe, step = loaded_pipeline(run_config)
    return pipe


@contextlib.contextmanager
def edited(pipeline, edit):
    """Load the pipeline's scene with ``edit(SceneTensors)`` applied; restore it afterwards."""
    original = {k: v.clone() for k, v in pipeline.state_dict().items()}
    scene = SceneTensors.from_state_dict(original, PREFIX)
    edit(scene)
    try:
        pipeline.load_pipeline(scene.to_state_dict(original, PREFIX), 0)
        yield scene
    finally:
        pipeline.load_pipeline(original, 0)


def render(pipeline, i: int) -> dict:
    cams = pipeline.datamanager.eval_dataset.cameras
    with torch.no_grad():
        return pipeline.model.get_outputs_for_camera(cams[i : i + 1])


def ids_of(pipeline, i: int) -> torch.Tensor:  # -> [H, W] int64
    return render(pipeline, i)["instance_id"][..., 0].long()


_BIGGEST: dict[int, tuple[int, int]] = {}


def biggest_instance(pipeline) -> tuple[int, int]:
    """(eval image, instance ID) with the largest rendered mask that does not touch the border
    (of the unedited scene; computed once per pipeline)."""
    if id(pipeline) not in _BIGGEST:
        _BIGGEST[id(pipeline)] = _find_biggest(pipeline)
    return _BIGGEST[id(pipeline)]


def _find_biggest(pipeline) -> tuple[int, int]:
    best = (0, -1, -1)
    for i in range(len(pipeline.datamanager.eval_dataset.cameras)):
        ids = ids_of(pipeline, i)
        for iid in ids.unique().tolist():
            mask = ids == iid
            border = mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()
            if iid > 0 and not border and int(mask.sum()) > best[0]:
                best = (int(mask.sum()), i, iid)
    assert best[2] > 0, "the tiny street must show an instance fully inside an eval image"
    return best[1], best[2]


def test_remove_turns_its_pixels_into_background(pipeline):
    i, iid = biggest_instance(pipeline)
    before = render(pipeline, i)
    mask = before["instance_id"][..., 0].long() == iid
    with edited(pipeline, lambda s: s.remove([iid])):
        after = render(pipeline, i)
        after_ids = after["instance_id"][..., 0].long()
        assert iid not in pipeline.model.scene_model.trajectories.instance_ids.tolist()
        assert not bool((pipeline.model.gaussians.instance_ids == iid).any())
    assert not bool((after_ids == iid).any())
    # Its pixels now show the background (static Gaussians or the background colour) ...
    assert float(((after_ids[mask] == 0) | (after_ids[mask] == -1)).float().mean()) > 0.9
    assert float((after["rgb"][mask] - before["rgb"][mask]).abs().mean()) > 0.01
    # ... and the rest of the picture is unchanged.
    assert bool((after_ids[~mask] == before["instance_id"][..., 0].long()[~mask]).float().mean() > 0.99)


def _centroid(mask: torch.Tensor) -> np.ndarray:
    v, u = torch.nonzero(mask, as_tuple=True)
    return np.array([u.float().mean().item(), v.float().mean().item()])


def _project(pipeline, i: int, point: np.ndarray) -> np.ndarray:
    cam = pipeline.datamanager.eval_dataset.cameras[i : i + 1]
    viewmat, K, _, _ = pipeline.model._camera_inputs(read_camera(cam), 1)
    p = viewmat[:3, :3].double() @ torch.as_tensor(point) + viewmat[:3, 3].double()
    uv = K.double() @ p
    return (uv[:2] / uv[2]).numpy()


def test_move_one_metre_shifts_the_mask_by_the_projected_offset(pipeline):
    i, iid = biggest_instance(pipeline)
    cam = pipeline.datamanager.eval_dataset.cameras[i : i + 1]
    t = float(cam.metadata["time_seconds"].reshape(-1)[0])
    traj = pipeline.model.scene_model.trajectories
    k = traj.instance_ids.tolist().index(iid)
    with torch.no_grad():
        R, trans, _ = traj.poses_at(pipeline.model.scene_model.camera_time(t, int(cam.metadata["sensor_idx"])))
    # The instance's visible centre: mean of its Gaussians, posed at the image's time.
    g = pipeline.model.gaussians
    centre = (R[k].double() @ g.means[g.instance_ids == iid].detach().double().mean(0) + trans[k].double()).numpy()
    # One metre along the camera's horizontal right axis (world frame), so the mask moves sideways.
    right = pipeline.model._camera_inputs(read_camera(cam), 1)[0][0, :3].double().numpy()
    right[2] = 0.0
    offset = right / np.linalg.norm(right)
    expected = _project(pipeline, i, centre + offset) - _project(pipeline, i, centre)
    before = _centroid(ids_of(pipeline, i) == iid)
    with edited(pipeline, lambda s: s.move(iid, tuple(offset), 0.0, "world")):
        after = _centroid(ids_of(pipeline, i) == iid)
    shift = after - before
    assert np.linalg.norm(expected) > 3.0  # a measurable offset on the tiny images
    assert np.linalg.norm(shift - expected) < 0.25 * np.linalg.norm(expected) + 1.0, (shift, expected)


def test_move_in_the_instance_frame_follows_its_heading():
    scene = _toy_scene()
    scene.move(7, (0.0, 1.0, 0.0), math.pi / 2, "instance")
    p = scene.trajectories["positions"][0]
    # heading +x at every step: one metre to its left is +y; the yaw turns it to face +y
    assert torch.allclose(p[:, 1], torch.ones(4), atol=1e-6) and torch.allclose(p[:, 0], torch.arange(4.0) * 2, atol=1e-6)
    R = scene.step_rotations()[0]
    assert torch.allclose(R[:, :3, 0], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(4, 3), atol=1e-6)


def _toy_scene() -> SceneTensors:
    """One instance (ID 7) driving along +x at 2 m per 0.1 s step over 4 steps, 10 Gaussians."""
    Z, F = 1, 4
    positions = torch.zeros(Z, F, 3)
    positions[0, :, 0] = torch.arange(F) * 2.0
    gaussians = {k: torch.zeros(10, d) for k, d in (("means", 3), ("scales", 3), ("features_rgb", 3), ("features", 13))}
    gaussians |= {"quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(10, 1), "opacities": torch.zeros(10),
                  "instance_ids": torch.tensor([0] * 5 + [7] * 5)}
    traj = {"positions": positions, "rotation_deltas": torch.zeros(Z, F, 3), "frame_times": torch.arange(F) * 0.1,
            "instance_ids": torch.tensor([7]), "span_first": torch.tensor([0]), "span_last": torch.tensor([F - 1]),
            "base_rotations": torch.eye(3).repeat(Z, F, 1, 1)}
    traj["frame_times"] = traj["frame_times"].double()
    return SceneTensors(gaussians, traj)


def test_retime_shifts_the_presence_span_and_the_motion():
    scene = _toy_scene()
    before = scene.as_trajectories()
    scene.retime(7, 0.1)
    after = scene.as_trajectories()
    assert (int(after.span_first[0]), int(after.span_last[0])) == (1, 3)
    assert not bool(after.present_at(0.0)[0]) and bool(before.present_at(0.0)[0])
    # where it was at t it is now at t + 0.1 s
    for t in (0.0, 0.1, 0.15):
        assert torch.allclose(after.poses_at(t + 0.1)[1], before.poses_at(t)[1], atol=1e-5)
    slow = _toy_scene()
    slow.retime(7, 0.0, 0.5)  # half speed: at 0.2 s it is where it was at 0.1 s, then the sequence ends
    traj = slow.as_trajectories()
    assert torch.allclose(traj.poses_at(0.2)[1], before.poses_at(0.1)[1], atol=1e-5)
    assert int(traj.span_last[0]) == 3
    with pytest.raises(EditError, match="no step"):
        _toy_scene().retime(7, 5.0)
    with pytest.raises(EditError, match="speed"):
        _toy_scene().retime(7, 0.0, 0.0)


def test_retime_in_a_render(pipeline):
    i, iid = biggest_instance(pipeline)
    traj = pipeline.model.scene_model.trajectories
    k = traj.instance_ids.tolist().index(iid)
    start = float(traj.frame_times[int(traj.span_first[k])])
    cam_time = float(pipeline.datamanager.eval_dataset.cameras[i : i + 1].metadata["time_seconds"].reshape(-1)[0])
    shift = cam_time - start + 0.15  # starts after this image was taken: gone from it
    with edited(pipeline, lambda s: s.retime(iid, shift)):
        assert not bool((ids_of(pipeline, i) == iid).any())


def test_duplicate_adds_a_new_instance(pipeline):
    i, iid = biggest_instance(pipeline)
    new_ids = []
    with edited(pipeline, lambda s: new_ids.append(s.duplicate(iid, (0.0, 0.0, 0.0)))):
        ids = ids_of(pipeline, i)
        g = pipeline.model.gaussians
        assert int((g.instance_ids == new_ids[0]).sum()) == int((g.instance_ids == iid).sum()) > 0
    assert new_ids[0] > max(pipeline.model.scene_model.trajectories.instance_ids.tolist())
    assert bool((ids == new_ids[0]).any())  # the copy sits on the original: both show


def test_unknown_id_is_an_error():
    with pytest.raises(EditError, match="no instance 99"):
        _toy_scene().move(99, (1.0, 0.0, 0.0))


def test_cli_writes_a_run_that_loads_like_any_run(run_config, pipeline, tmp_path, capsys):
    from nerfstudio.utils.eval_utils import eval_setup

    from idsplat_ns.cli.edit import main

    i, iid = biggest_instance(pipeline)
    out = tmp_path / "edited"
    main(["--load-config", str(run_config), "--output-dir", str(out), "--remove", str(iid), "--list"])
    listing = capsys.readouterr().out
    assert f"removed {iid}" in listing and "class" in listing
    assert (out / "config.yml").is_file() and len(list((out / "nerfstudio_models").glob("step-*.ckpt"))) == 1
    _, edited_pipeline, ckpt, _ = eval_setup(out / "config.yml", test_mode="test")
    assert ckpt.parent == out / "nerfstudio_models"
    assert iid not in edited_pipeline.model.scene_model.trajectories.instance_ids.tolist()
    assert not bool((ids_of(edited_pipeline, i) == iid).any())
    # --points adds each instance's lidar points, label and class from the run's (oracle) decomposition.
    main(["--load-config", str(run_config), "--list", "--points"])
    rows = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("│")]
    tracks = instance_inputs(pipeline.datamanager.train_dataset.metadata).tracks.instances
    expected = {t.instance_id: (len(t.canonical_points), t.label, label_group(t.label)) for t in tracks}
    for row in rows:
        cells = [c.strip() for c in row.strip("│").split("│")]
        n, label, cls = expected[int(cells[0])]
        assert (int(cells[-3]), cells[-2], cells[-1]) == (n, label, cls)
        assert cells[1] in ("vehicle", "pedestrian", "cyclist")  # the guess from size and speed
    assert len(rows) == len(expected) > 0
    # Unknown IDs end in one line naming the option's source and the known IDs.
    with pytest.raises(SystemExit) as exit_info:
        main(["--load-config", str(run_config), "--output-dir", str(tmp_path / "x"), "--move", "99", "1", "0", "0", "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(err) == 1 and "no instance 99" in err[0] and str(run_config) in err[0]


def test_move_in_the_world_frame_turns_the_path_about_its_centre():
    scene = _toy_scene()  # along +x from (0, 0) to (6, 0)
    scene.move(7, (0.0, 0.0, 0.5), math.pi / 2, "world")
    p = scene.trajectories["positions"][0].double()
    expected = torch.stack([torch.full((4,), 3.0), torch.arange(4.0) * 2 - 3, torch.full((4,), 0.5)], 1).double()
    assert torch.allclose(p, expected, atol=1e-5)


def test_removing_every_instance_leaves_the_static_scene(pipeline):
    i, _ = biggest_instance(pipeline)
    with edited(pipeline, lambda s: s.remove(s.instance_ids)):
        assert pipeline.model.scene_model.trajectories.num_instances == 0
        ids = ids_of(pipeline, i)
    assert not bool((ids > 0).any()) and bool((ids == 0).any())


@pytest.mark.parametrize("edit", [["--move", "1", "nan", "0", "0", "0"], ["--duplicate", "1", "0", "inf", "0"],
                                  ["--retime", "1", "0.5", "0"], ["--retime", "1", "nan"]])
def test_non_finite_edits_are_refused_before_anything_is_read_or_written(tmp_path, edit):
    from idsplat_ns.errors import IDSplatError
    from idsplat_ns.cli.edit import parse_args, run

    args = parse_args(["--load-config", str(tmp_path / "no-such-run" / "config.yml"), "--output-dir",
                       str(tmp_path / "edited"), *edit])  # fmt: skip
    with pytest.raises(IDSplatError, match="finite number|SPEED must be positive"):
        run(args)
    assert not (tmp_path / "edited").exists()
