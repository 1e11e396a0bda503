"""idsplat-export (issue 21): standard 3DGS .ply files of the static and instance Gaussians and of
the whole scene at a time, read back with plyfile, and the trajectories as JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("nerfstudio")
plyfile = pytest.importorskip("plyfile")

from _tiny_run import tiny_run  # noqa: E402

from idsplat_ns.model.editing import SceneTensors  # noqa: E402
from idsplat_ns.model.ply_export import SH_C0  # noqa: E402
from idsplat_ns.runs.run_folder import SCENE_PREFIX, load_run  # noqa: E402

ATTRIBUTES = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(45)]
              + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


@pytest.fixture(scope="module")
def exported(tiny_street, tmp_path_factory):
    from idsplat_ns.cli.export import export, parse_args

    config = tiny_run(tiny_street, tmp_path_factory)
    scene = SceneTensors.from_state_dict(load_run(config).pipeline_state, SCENE_PREFIX)
    out = tmp_path_factory.mktemp("export")
    traj = scene.as_trajectories()
    time = float(traj.frame_times[len(traj.frame_times) // 2]) + 0.03  # between two steps
    record = export(parse_args(["--load-config", str(config), "--output-dir", str(out), "--time", str(time)]))
    return out, scene, record, time


def _vertices(path) -> np.ndarray:
    return plyfile.PlyData.read(str(path))["vertex"].data


def test_static_and_instance_files_hold_their_gaussians(exported):
    out, scene, record, _ = exported
    g, ids = scene.gaussians, scene.gaussians["instance_ids"]
    static = _vertices(out / "static.ply")
    assert list(static.dtype.names) == ATTRIBUTES
    assert len(static) == int((ids == 0).sum()) > 0
    mine = ids == 0
    np.testing.assert_allclose(static["x"], g["means"][mine, 0].numpy(), atol=1e-6)
    np.testing.assert_allclose(static["opacity"], g["opacities"][mine].numpy(), atol=1e-6)  # logits
    np.testing.assert_allclose(static["scale_1"], g["scales"][mine, 1].numpy(), atol=1e-6)  # logs
    rgb = torch.sigmoid(g["features_rgb"][mine]).numpy()
    np.testing.assert_allclose(static["f_dc_2"] * SH_C0 + 0.5, rgb[:, 2], atol=1e-5)
    quat = np.stack([static[f"rot_{i}"] for i in range(4)], 1)
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-5)
    assert len(record["instances"]) == len(scene.instance_ids) > 0
    for inst in record["instances"]:
        v = _vertices(out / inst["ply"])
        assert len(v) == inst["num_gaussians"] == int((ids == inst["id"]).sum())
        np.testing.assert_allclose(v["y"], g["means"][ids == inst["id"], 1].numpy(), atol=1e-6)  # canonical frame


def test_trajectories_json_matches_the_model(exported):
    out, scene, _, _ = exported
    data = json.loads((out / "trajectories.json").read_text())
    traj = scene.as_trajectories()
    for inst in data["instances"]:
        k = traj.instance_ids.tolist().index(inst["id"])
        assert len(inst["times"]) == len(inst["poses"]) == int(traj.span_last[k] - traj.span_first[k]) + 1
        for t, pose in zip(inst["times"], inst["poses"]):
            T, present = traj.pose_matrices_at(t)
            assert bool(present[k])
            np.testing.assert_allclose(np.array(pose), T[k].double().numpy(), atol=1e-5)


def test_scene_at_a_time_places_present_instances(exported):
    out, scene, record, time = exported
    v = _vertices(out / record["scene_ply"])
    traj = scene.as_trajectories()
    T, present = traj.pose_matrices_at(time)
    ids = scene.gaussians["instance_ids"]
    present_ids = traj.instance_ids[present].tolist()
    assert 0 < len(present_ids)
    assert len(v) == int((ids == 0).sum()) + sum(int((ids == i).sum()) for i in present_ids)
    # The exported order is the model's: static and instance rows in their original order.
    keep = (ids == 0) | torch.isin(ids, torch.tensor(present_ids))
    kept_ids = ids[keep]
    iid = present_ids[0]
    k = traj.instance_ids.tolist().index(iid)
    canonical = scene.gaussians["means"][ids == iid].double()
    world = canonical @ T[k, :3, :3].double().T + T[k, :3, 3].double()
    xyz = np.stack([v["x"], v["y"], v["z"]], 1)[(kept_ids == iid).numpy()]
    np.testing.assert_allclose(xyz, world.numpy(), atol=1e-4)
    # an instance's world position differs from its canonical one: it was really placed
    assert np.abs(xyz - canonical.numpy()).max() > 1.0


def test_sh_rest_can_be_left_out(tiny_street, tmp_path_factory, tmp_path):
    from idsplat_ns.cli.export import export, parse_args

    config = tiny_run(tiny_street, tmp_path_factory)
    export(parse_args(["--load-config", str(config), "--output-dir", str(tmp_path), "--sh-rest", "0"]))
    names = _vertices(tmp_path / "static.ply").dtype.names
    assert not any(n.startswith("f_rest") for n in names) and "f_dc_0" in names and "rot_3" in names
