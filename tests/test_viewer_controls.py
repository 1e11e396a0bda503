"""The viewer's instance panel (issue 21) without a browser: hiding an instance renders as if it
were removed, the instance colours are categorical, the drawn trajectories are the poses at the
step times, the start view is behind the ego, the panel acts on viewer renders only, and saving
the hidden instances writes the run that ``idsplat-edit --remove`` writes."""

from __future__ import annotations

import json
import math
import threading
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from idsplat_ns.model.editing import SceneTensors
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.instance_palette import PALETTE, instance_colors, instance_rgb
from idsplat_ns.model.instance_visibility import highlight, render_camera_hiding, visible_mask
from idsplat_ns.model.scene_model import DecoderConfig, SceneModel
from idsplat_ns.model.trajectories import InstanceTrajectories

K = torch.tensor([[40.0, 0.0, 32.0], [0.0, 40.0, 24.0], [0.0, 0.0, 1.0]])
W, H = 64, 48
TIMES = np.array([0.0, 0.1, 0.2, 0.3])


def _pose(x: float, y: float, yaw: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [x, y, 6.0]
    return T


def _scene(ids_of_gaussians: torch.Tensor, means: torch.Tensor, trajectories) -> SceneModel:
    g = GaussianSet(len(means), feature_dim=4)
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        g.means.copy_(means)
        g.scales.fill_(math.log(0.25))
        g.opacities.fill_(2.0)
        g.features_rgb.copy_(torch.randn(len(means), 3, generator=gen))
        g.features.copy_(torch.randn(len(means), 4, generator=gen) * 0.1)
        g.instance_ids.copy_(ids_of_gaussians)
    sm = SceneModel(g, 1, DecoderConfig(feature_dim=4), trajectories)
    torch.nn.init.normal_(sm.rgb_decoder.out.weight, std=0.1)  # a decoder that mixes neighbours
    return sm.eval()


@pytest.fixture(scope="module")
def scene_model() -> SceneModel:
    """A static wall (ID 0) behind two instances (IDs 3 and 7) that move across the view."""
    gen = torch.Generator().manual_seed(0)
    wall = torch.cat([torch.rand(300, 2, generator=gen) * 8 - 4, torch.full((300, 1), 10.0)], 1)
    wall = wall[:, [0, 1, 2]]
    blob = torch.randn(60, 3, generator=gen) * 0.4  # canonical frame
    means = torch.cat([wall, blob, blob.clone()])
    ids = torch.cat([torch.zeros(300), torch.full((60,), 3), torch.full((60,), 7)]).long()
    # Camera: identity world-to-camera (OpenCV, z forward); instances 6 m ahead, moving in x.
    poses = np.stack([[_pose(-1.5 + 0.5 * k, -0.5, 0.1 * k) for k in range(4)],
                      [_pose(1.5 - 0.5 * k, 0.8) for k in range(4)]])
    traj = InstanceTrajectories(TIMES, np.array([3, 7]), poses, np.ones((2, 4), bool), refine=False)
    # world = camera frame here, so "up" is -y; the poses only need to put the blobs in view
    return _scene(ids, means, traj)


def _without(sm: SceneModel, remove: list[int], drop_static: bool = False) -> SceneModel:
    """The same scene with instances removed by editing.py (and the static Gaussians dropped)."""
    scene = SceneTensors.from_state_dict(sm.state_dict())
    scene.remove(remove)
    if drop_static:
        keep = scene.gaussians["instance_ids"] != 0
        scene.gaussians = {k: v[keep] for k, v in scene.gaussians.items()}
    state = scene.to_state_dict(sm.state_dict())
    Z, F = scene.trajectories["positions"].shape[:2]
    out = _scene(scene.gaussians["instance_ids"], scene.gaussians["means"],
                 InstanceTrajectories.placeholder(Z, F, refine=False))
    out.load_state_dict(state)
    out.trajectories.reset_span_margin()
    return out


def _render(sm, hidden=()) -> dict:
    with torch.no_grad():
        return render_camera_hiding(sm, hidden, torch.eye(4), K, W, H, 0.15, 0)


@pytest.mark.parametrize("hidden", [[3], [3, 7]])
def test_hiding_instances_renders_like_removing_them(scene_model, hidden):
    full, hid, ref = _render(scene_model), _render(scene_model, hidden), _render(_without(scene_model, hidden))
    for key in ("rgb", "depth", "accumulation", "instance_id"):
        torch.testing.assert_close(hid[key], ref[key], atol=1e-5, rtol=1e-5)
    for iid in hidden:
        mine = full["instance_id"][..., 0] == iid
        assert int(mine.sum()) > 30, "the instance must be in view for the test to mean anything"
        assert not bool((hid["instance_id"][..., 0] == iid).any())
        assert float((full["rgb"] - hid["rgb"]).abs().sum(-1)[mine].mean()) > 0.05  # its pixels changed


def test_hiding_the_static_background(scene_model):
    hid, ref = _render(scene_model, [0]), _render(_without(scene_model, [], drop_static=True))
    torch.testing.assert_close(hid["rgb"], ref["rgb"], atol=1e-5, rtol=1e-5)
    assert set(hid["instance_id"].unique().long().tolist()) <= {-1, 3, 7}


def test_visible_mask_and_highlight():
    ids = torch.tensor([0, 3, 3, 7, 0])
    assert visible_mask(ids, {3}).tolist() == [True, False, False, True, True]
    assert visible_mask(ids, []).all()
    rgb = torch.zeros(2, 2, 3)
    id_map = torch.tensor([[[3.0], [0.0]], [[-1.0], [3.0]]])
    out = highlight(rgb, id_map, 3, strength=0.5)
    expected = 0.5 * torch.tensor(instance_rgb(3))
    torch.testing.assert_close(out[0, 0], expected)
    torch.testing.assert_close(out[1, 1], expected)
    assert float(out[0, 1].abs().sum()) == 0.0 and float(out[1, 0].abs().sum()) == 0.0


def test_instance_colours_are_categorical_and_stable():
    from skimage.color import deltaE_ciede2000, rgb2lab

    first = np.array([instance_rgb(i) for i in range(1, 33)])  # [32, 3]
    lab = rgb2lab(first[None])[0]
    d = deltaE_ciede2000(lab[:, None], lab[None])
    d[np.arange(32), np.arange(32)] = np.inf
    assert d.min() > 8.0, f"two of the first 32 instance colours differ by only {d.min():.1f} (CIEDE2000)"
    special = rgb2lab(np.array([[instance_rgb(0), instance_rgb(-1)]]))[0]  # static grey, empty black
    assert deltaE_ciede2000(lab[:, None], special[None]).min() > 10.0
    ids = torch.tensor([[-1, 0, 1], [5, 300, 1]])
    img = instance_colors(ids)
    for (r, c), iid in np.ndenumerate(ids.numpy()):
        torch.testing.assert_close(img[r, c], torch.tensor(instance_rgb(int(iid)), dtype=torch.float32))
    torch.testing.assert_close(img[0, 2], img[1, 2])  # one ID, one colour wherever it is
    assert instance_rgb(300) == instance_rgb(300 - len(PALETTE))  # the palette repeats after 256


def test_trajectory_polylines_are_the_poses_at_the_step_times():
    from idsplat_ns.nerfstudio.viewer_scene import marker_positions, trajectory_polylines

    times = np.array([0.0, 0.1, 0.25, 0.4, 0.5])
    poses = np.stack([[_pose(k, 2.0 * k, 0.2 * k) for k in range(5)] for _ in range(3)])
    valid = np.array([[True] * 5, [False, True, False, True, False], [False] * 5])
    traj = InstanceTrajectories(times, np.array([2, 5, 9]), poses, valid, refine=True)
    with torch.no_grad():
        traj.positions.add_(torch.randn(traj.positions.shape) * 0.1)  # learnt values, not the initial ones
    lines = trajectory_polylines(traj)
    assert sorted(lines) == [2, 5]  # instance 9 has no valid step: nothing to draw
    for z, iid in enumerate([2, 5]):
        steps = np.flatnonzero(valid[z])
        span = range(steps[0], steps[-1] + 1)  # gaps inside the span are steps too
        expected = np.stack([traj.poses_at(float(times[k]))[1][z].detach().double().numpy() for k in span])
        np.testing.assert_allclose(lines[iid], expected, atol=1e-6)
    markers = marker_positions(traj, 0.175)  # between steps: the interpolated pose
    np.testing.assert_allclose(markers[2][0], traj.poses_at(0.175)[1][0].detach().numpy(), atol=1e-6)
    assert markers[2][1] and markers[5][1]
    before = marker_positions(traj, 0.0)[5]  # instance 5 starts at step 1 (minus a margin)
    assert not before[1]
    np.testing.assert_allclose(before[0], lines[5][0], atol=1e-6)  # waits at the start of its path


def _camera_image(name, time, c2w):
    return SimpleNamespace(camera=name, time=time, camera_to_world=c2w,
                           intrinsics=SimpleNamespace(height=80, fy=83.4))


def test_start_view_is_behind_the_ego_looking_ahead():
    from idsplat_ns.nerfstudio.viewer_scene import front_camera, start_view

    assert front_camera(["FRONT_LEFT", "FRONT", "SIDE_LEFT"]) == "FRONT"
    assert front_camera(["left", "right"]) == "left"
    yaw = 0.6
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    c2w = np.eye(4)  # OpenCV camera looking along fwd, pitched 5 degrees down
    pitch = math.radians(5)
    z = math.cos(pitch) * fwd + np.array([0, 0, -math.sin(pitch)])
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    c2w[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    c2w[:3, 3] = [3.0, 1.0, 1.6]
    images = {"front_camera": [_camera_image("front_camera", 0.5, c2w), _camera_image("front_camera", 0.0, c2w)],
              "front_left_camera": [_camera_image("front_left_camera", 0.0, np.eye(4))]}
    scene = SimpleNamespace(camera_names=["front_left_camera", "front_camera"], images_of=lambda n: images[n])
    view = start_view(scene, back=8.0, above=2.5, ahead=12.0)
    np.testing.assert_allclose(view.position, c2w[:3, 3] - 8 * fwd + [0, 0, 2.5], atol=1e-9)
    np.testing.assert_allclose(view.look_at, c2w[:3, 3] + 12 * fwd, atol=1e-9)
    assert view.fov_y == pytest.approx(2 * math.atan(40 / 83.4))
    pose = view.camera_to_world()
    assert pose[:3, 2] @ fwd > 0.99 and pose[:3, 2][2] < 0  # looks ahead, a little down
    assert abs(pose[:3, 0][2]) < 1e-9 and pose[:3, 1][2] < 0  # level horizon, image y points down
    assert (c2w[:3, 3] - pose[:3, 3]) @ fwd == pytest.approx(8.0)  # 8 m behind the camera


def test_the_panel_acts_on_viewer_render_threads_only():
    from nerfstudio.viewer.render_state_machine import RenderStateMachine

    from idsplat_ns.nerfstudio.viewer_controls import InstanceControls

    controls = InstanceControls(model=None, start=None)
    controls.hidden = frozenset({4})
    seen = {}

    class FakeRenderThread(RenderStateMachine):
        def __init__(self):  # noqa: D401  (no viewer: only the thread's class matters)
            threading.Thread.__init__(self)

        def run(self):
            seen["viewer"] = controls.hidden_now()

    other = threading.Thread(target=lambda: seen.update(other=controls.hidden_now()))
    for thread in (FakeRenderThread(), other):
        thread.start()
        thread.join()
    assert seen == {"viewer": frozenset({4}), "other": frozenset()}
    assert controls.hidden_now() == frozenset()  # the trainer's thread


def test_the_run_config_is_found_for_trained_edited_and_training_runs(tmp_path):
    from idsplat_ns.nerfstudio.viewer_controls import config_candidates

    # ns-viewer writes its log into the config's base folder: the run folder of a trained run,
    # DIR/<experiment>/<method> of a run that idsplat-edit wrote to DIR.
    trained = SimpleNamespace(trainer=None, log_filename=tmp_path / "exp/m/2024/viewer_log_filename.txt")
    assert config_candidates(trained)[0] == tmp_path / "exp/m/2024/config.yml"
    edited = SimpleNamespace(trainer=None, log_filename=tmp_path / "DIR/exp/m/viewer_log_filename.txt")
    assert tmp_path / "DIR/config.yml" in config_candidates(edited)
    training = SimpleNamespace(trainer=SimpleNamespace(base_dir=tmp_path / "run"), log_filename=tmp_path / "x.txt")
    assert config_candidates(training) == [tmp_path / "run/config.yml"]


# ---------------------------------------------------------------------------------------------
# on the shared tiny run (see tests/_tiny_run.py)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def run_config(tiny_street, tmp_path_factory):
    from _tiny_run import tiny_run

    return tiny_run(tiny_street, tmp_path_factory)


def test_saving_hidden_instances_writes_the_run_idsplat_edit_writes(run_config, tmp_path):
    from idsplat_ns.errors import IDSplatError
    from idsplat_ns.cli.edit import main as edit_main
    from idsplat_ns.runs.run_folder import SCENE_PREFIX, load_run
    from idsplat_ns.nerfstudio.viewer_controls import save_hidden_as_run

    source = load_run(run_config)
    ids = SceneTensors.from_state_dict(source.pipeline_state, SCENE_PREFIX).instance_ids
    assert len(ids) >= 2
    hidden = frozenset({0, ids[0], ids[-1]})  # the static background is kept on saving
    written, done = save_hidden_as_run(run_config, source.pipeline_state, source.step, hidden, tmp_path / "viewer")
    assert done == [f"removed {ids[0]} {ids[-1]}"]
    edit_main(["--load-config", str(run_config), "--output-dir", str(tmp_path / "cli"),
               "--remove", str(ids[0]), str(ids[-1])])
    ours, theirs = load_run(written), load_run(tmp_path / "cli" / "config.yml")
    assert ours.step == theirs.step == source.step
    assert ours.pipeline_state.keys() == theirs.pipeline_state.keys()
    for key, value in theirs.pipeline_state.items():
        torch.testing.assert_close(ours.pipeline_state[key], value, msg=key)
    record = json.loads((written.parent / "edits.json").read_text())
    assert record["edits"] == done and record["saved_from"] == f"the viewer's live model at step {source.step}"
    assert record["source_checkpoint"] == str(source.checkpoint_path.resolve())
    with pytest.raises(IDSplatError, match="Run config .* is not a file"):
        save_hidden_as_run(tmp_path / "nowhere.yml", source.pipeline_state, source.step, hidden, tmp_path / "x")
    with pytest.raises(IDSplatError, match="no instance is hidden"):
        save_hidden_as_run(run_config, source.pipeline_state, source.step, frozenset({0}), tmp_path / "none")
    with pytest.raises(IDSplatError, match="source run's folder"):
        save_hidden_as_run(run_config, source.pipeline_state, source.step, hidden, run_config.parent)


def test_the_model_hides_in_viewer_renders_and_adds_instance_colours(run_config):
    from _tiny_run import loaded_pipeline
    from nerfstudio.viewer.render_state_machine import RenderStateMachine

    pipeline, _ = loaded_pipeline(run_config)
    model = pipeline.model
    cams = pipeline.datamanager.eval_dataset.cameras
    full = model.get_outputs_for_camera(cams[0:1])
    ids = full["instance_id"][..., 0].long()
    shown = [int(i) for i in ids.unique() if i > 0]
    assert shown, "an eval image of the tiny street shows an instance"
    target = max(shown, key=lambda i: int((ids == i).sum()))
    torch.testing.assert_close(full["instances"], instance_colors(ids))
    got = {}

    class FakeRenderThread(RenderStateMachine):
        def __init__(self):
            threading.Thread.__init__(self)

        def run(self):
            got["viewer"] = model.get_outputs_for_camera(cams[0:1])

    model.viewer_controls.hidden = frozenset({target})
    try:
        main_thread = model.get_outputs_for_camera(cams[0:1])  # evaluation: never hidden
        thread = FakeRenderThread()
        thread.start()
        thread.join()
    finally:
        model.viewer_controls.hidden = frozenset()
    torch.testing.assert_close(main_thread["rgb"], full["rgb"])
    viewer_ids = got["viewer"]["instance_id"][..., 0].long()
    assert not bool((viewer_ids == target).any())
    assert float((got["viewer"]["rgb"] - full["rgb"]).abs()[ids == target].mean()) > 0.01
