"""Only what the scene has: cameras without training images get no embedding, scenes without
lidar no lidar head or losses, instances that do not move no trajectory; the summary printed
before training and written as scene_summary.json in the run folder says so."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.static_conversion import StaticConversionConfig, static_reason
from idsplat_ns.instances.tracks import InstanceTrack
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.scene_model import DecoderConfig, SceneModel
from idsplat_ns.model.scene_summary import gaussian_counts, parameter_counts
from idsplat_ns.nerfstudio.model_inputs import INSTANCES_KEY, SPLIT_KEY, instance_inputs, split_data

STEPS = 3


def _track(iid: int, xs, valid=None) -> InstanceTrack:
    F = len(xs)
    poses = np.tile(np.eye(4), (F, 1, 1))
    poses[:, 0, 3] = xs
    return InstanceTrack(instance_id=iid, label="car", canonical_points=np.zeros((20, 3)), canonical_colors=None,
                         poses=poses, valid=np.ones(F, bool) if valid is None else np.asarray(valid),
                         point_counts=np.full(F, 20), fitness=np.ones(F), canonical_frame=0)  # fmt: skip


def test_counts_of_gaussians_and_parameters():
    ids = torch.tensor([0, 0, 3, 0, 7, 3, 3])
    assert gaussian_counts(ids) == {"total": 7, "static": 3, "instance 3": 3, "instance 7": 1}
    groups = {"a": [torch.nn.Parameter(torch.zeros(4, 3))], "b": [torch.nn.Parameter(torch.zeros(2)), torch.nn.Parameter(torch.zeros(5))]}
    assert parameter_counts(groups) == {"a": 12, "b": 7}


def test_why_an_instance_is_static():
    cfg = StaticConversionConfig()
    assert static_reason(_track(1, [0.0, 0.3, 0.5]), cfg) == "moved 0.50 m, under 1 m"
    assert static_reason(_track(2, [0.0, 5.0, 9.0], valid=[False, True, False]), cfg).startswith("seen in 1 frame")
    assert "world overlap" in static_reason(_track(3, [0.0, 5.0, 9.0]), cfg, {"static_by_world_overlap": [3]})


def test_the_static_threshold_follows_the_option_then_the_preprocessing():
    from idsplat_ns.instances.static_conversion import static_threshold
    from idsplat_ns.instances.tracks import InstanceTracks

    tracks = InstanceTracks(np.arange(3), np.arange(3) * 0.1, [_track(1, [0.0, 0.4, 0.7])], [], {"static_min_displacement": 0.5})
    assert static_threshold(None, tracks) == 0.5  # the model does not undo a smaller preprocessing threshold
    assert static_threshold(2.0, tracks) == 2.0 and static_threshold(None, None) == 1.0
    assert static_threshold(None, replace(tracks, metadata={})) == 1.0


def test_a_camera_without_training_images_has_no_embedding_and_renders_as_zero():
    g = GaussianSet(30)
    with torch.no_grad():
        g.means.copy_(torch.randn(30, 3, generator=torch.Generator().manual_seed(0)) + torch.tensor([0.0, 0.0, 4.0]))
        g.scales.fill_(math.log(0.3))
    sm = SceneModel(g, 3, DecoderConfig(), embedded_sensors=[0, 2])
    assert sm.sensor_embedding.weight.shape == (2, 8) and sm.sensor_rows == [0, -1, 1]
    torch.nn.init.normal_(sm.rgb_decoder.out.weight, std=0.5)  # make the embedding matter
    with torch.no_grad():
        sm.sensor_embedding.weight.normal_()
    K = torch.tensor([[20.0, 0, 8], [0, 20, 6], [0, 0, 1]])
    rgb = {s: sm.render_camera(torch.eye(4), K, 16, 12, None, sensor=s)["rgb"] for s in range(3)}
    with torch.no_grad():
        sm.sensor_embedding.weight.zero_()
    zero = sm.render_camera(torch.eye(4), K, 16, 12, None, sensor=0)["rgb"]
    torch.testing.assert_close(rgb[1], zero)  # the camera without an embedding renders with zeros
    assert not torch.allclose(rgb[0], zero) and not torch.allclose(rgb[2], zero)
    with pytest.raises(ValueError, match="embedded_sensors"):
        SceneModel(GaussianSet(1), 2, DecoderConfig(), embedded_sensors=[2])


# ---------------------------------------------------------------------------------------------
# through nerfstudio, on the tiny street
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def trained(tiny_street, tmp_path_factory):
    """An oracle run of STEPS steps (instances move, lidar, three cameras) and what it printed."""
    pytest.importorskip("nerfstudio")
    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", STEPS, (10**6, 10**6), fast=True)
    cfg.pipeline.datamanager.dataparser.data = tiny_street
    cfg.pipeline.datamanager.instance_mode = "oracle"
    cfg.pipeline.model.max_lidar_points = 6_000
    cfg.pipeline.model.num_random_points = 1_000
    cfg.pipeline.model.lidar.rays_per_step = 512
    cfg.vis = "tensorboard"
    cfg.output_dir = tmp_path_factory.mktemp("summary_run")
    cfg.steps_per_eval_image = 10**9
    cfg.set_timestamp()
    cfg.save_config()
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    before = json.loads((trainer.base_dir / "scene_summary.json").read_text())
    trainer.train()
    return trainer, cfg, before


def _metadata_with(dm, **changes) -> dict:
    """The training dataset's metadata with fields of its SplitData (``scene``, ``images``) or its
    InstanceInputs (``tracks``, ``mode``, ``test_mode``) changed."""
    meta = dict(dm.train_dataset.metadata)
    split, inputs = split_data(meta), instance_inputs(meta)
    split_fields = {k: v for k, v in changes.items() if k in ("scene", "images")}
    meta[SPLIT_KEY] = replace(split, **split_fields)
    meta[INSTANCES_KEY] = replace(inputs, **{k: v for k, v in changes.items() if k not in split_fields})
    return meta


def _model_with(trained, **changes):
    """The run's model built again from its metadata with some parts changed (training mode)."""
    trainer, cfg, _ = trained
    dm = trainer.pipeline.datamanager
    return cfg.pipeline.model.setup(scene_box=dm.train_dataset.scene_box, num_train_data=len(dm.train_dataset),
                                    metadata=_metadata_with(dm, **changes), device="cpu", grad_scaler=None)  # fmt: skip


def test_the_camera_backend_option_reaches_the_scene_model(trained, tmp_path):
    trainer, cfg, _ = trained
    assert trainer.pipeline.model.scene_model.camera_backend == "auto"
    dm = trainer.pipeline.datamanager
    model = replace(cfg.pipeline.model, camera_backend="torch").setup(
        scene_box=dm.train_dataset.scene_box, num_train_data=len(dm.train_dataset),
        metadata=dm.train_dataset.metadata, device="cpu", grad_scaler=None)  # fmt: skip
    assert model.scene_model.camera_backend == "torch"
    # gsplat on the CPU is refused with the other settings checks, before anything is read or written
    on_cpu = replace(cfg, output_dir=tmp_path / "runs", machine=replace(cfg.machine, device_type="cpu"),
                     pipeline=replace(cfg.pipeline, model=replace(cfg.pipeline.model, camera_backend="gsplat")))  # fmt: skip
    with pytest.raises(IDSplatError, match="camera-backend gsplat needs a CUDA device .* use auto or torch"):
        on_cpu.save_config()
    assert not (tmp_path / "runs").exists()


def test_summary_json_is_written_before_training_and_with_the_last_checkpoint(trained):
    trainer, _, before = trained
    model = trainer.pipeline.model
    after = json.loads((trainer.base_dir / "scene_summary.json").read_text())
    assert before["step"] is None and after["step"] == STEPS - 1
    # Beside nerfstudio_models/, which must hold checkpoints only: its loaders parse every name.
    assert [p.name for p in trainer.checkpoint_dir.iterdir()] == [f"step-{STEPS - 1:09d}.ckpt"]
    sm = model.scene_model
    Z, F = sm.trajectories.positions.shape[:2]
    assert after["moving_instances"] == sm.trajectories.instance_ids.tolist() and Z >= 1
    assert after["trajectory_parameters"] == Z * F * 6  # a position and an so(3) correction per step
    assert after["lidar_head"] and after["lidar_head_parameters"] == 13 * 32 + 32 + 32 * 2 + 2
    assert after["embedding_parameters"] == 3 * 8 and after["cameras_unused"] == []
    assert after["camera_time_offset_parameters"] == 3
    g = after["gaussians"]
    assert g["total"] == model.gaussians.num and g["static"] + sum(v for k, v in g.items() if k.startswith("instance ")) == g["total"]
    assert g["static"] == int((model.gaussians.instance_ids == 0).sum())
    N = g["total"]
    per_gaussian = {"means": 3, "scales": 3, "quats": 4, "opacities": 1, "features_rgb": 3, "features": 13}
    assert {k: after["parameters"][k] for k in per_gaussian} == {k: n * N for k, n in per_gaussian.items()}
    assert after["parameters"]["trajectory_positions"] + after["parameters"]["trajectory_rotations"] == Z * F * 6
    assert after["parameters"]["lidar_head"] == after["lidar_head_parameters"]
    assert after["parameters"]["sensor_embeddings"] == 3 * 8 and after["parameters"]["camera_time_offsets"] == 3


def test_the_run_still_loads_as_ns_eval_loads_it(trained):
    from nerfstudio.utils.eval_utils import eval_setup

    trainer, cfg, _ = trained
    _, pipeline, _, step = eval_setup(cfg.get_base_dir() / "config.yml", test_mode="test")
    assert step == STEPS - 1
    loaded, model = pipeline.model.scene_model, trainer.pipeline.model.scene_model
    assert loaded.sensor_rows == model.sensor_rows and torch.equal(loaded.sensor_embedding.weight, model.sensor_embedding.weight)


def test_summary_is_printed_once_before_training(trained, capsys):
    _model_with(trained)
    out = capsys.readouterr().out
    assert out.count("IDSplat models:") == 1
    assert "lidar head" in out and "moving with trajectories" in out and "cameras: 3 with training images" in out


def test_an_instance_that_does_not_move_gets_no_trajectory(trained):
    tracks = instance_inputs(trained[0].pipeline.datamanager.train_dataset.metadata).tracks
    first = tracks.instances[0]
    stopped = replace(first, poses=np.repeat(first.poses[first.canonical_frame][None], len(first.poses), 0))
    model = _model_with(trained, tracks=replace(tracks, instances=[stopped] + tracks.instances[1:]))
    s = model.scene_summary()
    assert first.instance_id not in s.moving_instances and len(s.moving_instances) == len(tracks.instances) - 1
    assert [st.instance_id for st in s.static_instances] == [first.instance_id]
    assert s.static_instances[0].reason == "moved 0.00 m, under 1 m"
    assert f"instance {first.instance_id}" not in s.gaussians  # its lidar points are static Gaussians
    assert s.trajectory_parameters == (len(tracks.instances) - 1) * len(tracks.frame_times) * 6


def test_a_scene_with_no_moving_object_has_no_trajectory_parameters(trained):
    tracks = instance_inputs(trained[0].pipeline.datamanager.train_dataset.metadata).tracks
    parked = [replace(i, poses=np.repeat(i.poses[i.canonical_frame][None], len(i.poses), 0)) for i in tracks.instances]
    model = _model_with(trained, tracks=replace(tracks, instances=parked))
    groups = model.get_param_groups()
    assert model.scene_model.trajectories is None and model.scene_model.camera_time_offset is None
    assert not any(k.startswith("trajectory") or k == "camera_time_offsets" for k in groups)
    s = model.scene_summary()
    assert s.trajectory_parameters == 0 and s.moving_instances == [] and len(s.static_instances) == len(tracks.instances)
    assert set(s.gaussians) == {"total", "static"}


def test_a_scene_without_lidar_has_no_lidar_head_and_no_lidar_losses(trained):
    trainer = trained[0]
    dm = trainer.pipeline.datamanager
    scene = split_data(dm.train_dataset.metadata).scene
    model = _model_with(trained, scene=replace(scene, lidar=[]), tracks=None, mode="static")
    assert model.scene_model.lidar_head is None and model.lidar is None
    assert "lidar_head" not in model.get_param_groups()
    model.train()
    camera, batch = dm.next_train(0)
    losses = model.get_loss_dict(model.get_outputs(camera), batch)
    assert not any(k.startswith("lidar") for k in losses)
    s = model.scene_summary()
    assert not s.lidar_head and s.lidar_head_parameters == 0 and s.lidar_training_sweeps == 0


def test_a_camera_without_training_images_gets_no_embedding(trained):
    split = split_data(trained[0].pipeline.datamanager.train_dataset.metadata)
    names = split.camera_names
    images = [im for im in split.images if im.camera != names[1]]
    model = _model_with(trained, images=images)
    s = model.scene_summary()
    assert s.cameras_unused == [names[1]] and s.cameras_used == [names[0], names[2]]
    assert s.embedding_parameters == 2 * 8 and model.scene_model.sensor_rows == [0, -1, 1]
    assert s.camera_time_offset_parameters == 2


def test_only_pedestrians_and_cyclists_deform_and_checkpoints_keep_the_choice(trained):
    from nerfstudio.engine.optimizers import Optimizers

    from idsplat_ns.model.deformation import DeformationConfig

    trainer, cfg, _ = trained
    dm = trainer.pipeline.datamanager
    tracks = instance_inputs(dm.train_dataset.metadata).tracks
    walker = replace(tracks.instances[0], label="pedestrian")
    with_people = replace(tracks, instances=[walker] + tracks.instances[1:])

    def build(enabled: bool, **meta):
        model_cfg = replace(cfg.pipeline.model, deformation=DeformationConfig(enabled=enabled))
        return model_cfg.setup(scene_box=dm.train_dataset.scene_box, num_train_data=len(dm.train_dataset),
                               metadata=_metadata_with(dm, **meta), device="cpu", grad_scaler=None)

    assert build(True).scene_model.deformation is None  # cars only: nothing deforms
    model = build(True, tracks=with_people)
    deform = model.scene_model.deformation
    assert deform.instance_ids.tolist() == [walker.instance_id]
    s = model.scene_summary()
    assert s.deformable_instances == [walker.instance_id]
    steps = len(deform.codes[0])
    # Codes (one instance, 8 per step) and the MLP 35 -> 64 -> 64 -> 3 (position, sin and cos of 4 frequencies, code).
    assert s.parameters["deformation"] == steps * 8 + (35 * 64 + 64) + (64 * 64 + 64) + (64 * 3 + 3)
    Optimizers(cfg.optimizers, model.get_param_groups())  # the method has an optimiser for the group
    with torch.no_grad():
        deform.mlp[-1].bias.fill_(0.3)
    # ns-eval builds the model without instances' settings and takes the checkpoint's shape.
    loaded = build(False, tracks=with_people, test_mode="test")
    assert loaded.scene_model.deformation is None
    loaded.load_state_dict(model.state_dict())
    t = float(tracks.frame_times[1])
    assert torch.equal(loaded.scene_model.posed_gaussians(t)["means"], model.scene_model.posed_gaussians(t)["means"])
    rigid = build(True, tracks=with_people, test_mode="test")
    rigid.load_state_dict(trainer.pipeline.model.state_dict())
    assert rigid.scene_model.deformation is None
