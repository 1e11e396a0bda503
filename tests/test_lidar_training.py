"""Lidar path wired into the nerfstudio model (tiny street, CPU): losses in the training step,
parameter groups, whole-sweep renders and the Table-2 metrics in ns-eval, camera-only scenes
without a lidar head, learnable camera time offsets."""

from __future__ import annotations
from idsplat_ns.nerfstudio.model_inputs import split_data

import math
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("nerfstudio")


def _trainer(data: Path, out: Path, mode: str = "static", load_lidar: bool = True, **lidar):
    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", 100, (1000, 2000), fast=True)
    cfg.pipeline.datamanager.dataparser.data = data
    cfg.pipeline.datamanager.dataparser.load_lidar = load_lidar
    cfg.pipeline.datamanager.instance_mode = mode
    cfg.pipeline.model.max_lidar_points = 6_000
    cfg.pipeline.model.num_random_points = 1_000
    cfg.pipeline.model.lidar.rays_per_step = 1024
    cfg.pipeline.model.lidar.eval_max_rays_per_sweep = 2048
    for key, value in lidar.items():
        setattr(cfg.pipeline.model.lidar, key, value)
    cfg.vis = "tensorboard"
    cfg.output_dir = out
    cfg.steps_per_eval_image = 10**9
    cfg.set_timestamp()
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer


@pytest.fixture(scope="module")
def lidar_trainer(tiny_street, tmp_path_factory):
    return _trainer(tiny_street, tmp_path_factory.mktemp("lidar_train"))


def _step(trainer, step: int) -> dict:
    trainer.pipeline.model.step = step
    trainer.optimizers.zero_grad_all()
    _, losses, _ = trainer.pipeline.get_train_loss_dict(step=step)
    sum(losses.values()).backward()
    return losses


def test_training_step_adds_the_lidar_losses_with_gradients(lidar_trainer):
    model = lidar_trainer.pipeline.model
    assert model.scene_model.lidar_head is not None and model.lidar is not None
    groups = model.get_param_groups()
    assert groups["lidar_head"] == list(model.scene_model.lidar_head.parameters())
    assert "lidar_head" in lidar_trainer.optimizers.optimizers  # the config has the group
    assert "camera_time_offsets" not in groups  # a static scene: nothing for a time offset to move
    losses = _step(lidar_trainer, 0)
    for key in ("lidar_depth", "lidar_intensity", "lidar_ray_drop", "lidar_line_of_sight"):
        assert key in losses and torch.isfinite(losses[key]) and losses[key].item() >= 0
    assert losses["lidar_depth"].item() > 0
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.scene_model.lidar_head.parameters())
    # Only the sweeps of training frames are sampled.
    train_frames = {im.frame_index for im in split_data(lidar_trainer.pipeline.datamanager.train_dataset.metadata).images}
    assert {s.frame_index for s in model.lidar.sweeps} == train_frames


def test_lidar_cadence_skips_steps(lidar_trainer):
    model = lidar_trainer.pipeline.model
    assert model.config.lidar.every_n_steps == 4  # the idsplat-fast preset
    previous, model.lidar.config.every_n_steps = model.lidar.config.every_n_steps, 3
    try:
        assert "lidar_depth" not in _step(lidar_trainer, 1)
        assert "lidar_depth" in _step(lidar_trainer, 3)
    finally:
        model.lidar.config.every_n_steps = previous


def test_lidar_losses_decrease_when_optimised(tiny_street, tmp_path):
    trainer = _trainer(tiny_street, tmp_path)
    model = trainer.pipeline.model
    model.train()
    first, last = [], []
    for step in range(12):
        rays, pose = model.lidar.sample(model.device)
        out = model.lidar.render_batch(model.scene_model, rays, pose)
        losses = model.lidar.losses(out)
        trainer.optimizers.zero_grad_all()
        sum(losses.values()).backward()
        trainer.optimizers.optimizer_step_all()
        total = float(sum(v.detach() for v in losses.values()))
        (first if step < 3 else last if step >= 9 else []).append(total)
    print(f"lidar loss: first steps {np.mean(first):.3f}, last steps {np.mean(last):.3f}")
    assert np.mean(last) < 0.8 * np.mean(first)


def test_sweep_render_and_eval_metrics(lidar_trainer):
    pipeline = lidar_trainer.pipeline
    model = pipeline.model
    sweeps = pipeline._held_out_sweeps()
    eval_frames = {im.frame_index for im in split_data(pipeline.datamanager.eval_dataset.metadata).images}
    assert sweeps and {s.frame_index for s in sweeps} == eval_frames
    model.eval()
    render = model.render_lidar_sweep(sweeps[0])
    model.train()
    n = render.rays.num_rays
    assert n == 2048 and render.range.shape == render.intensity.shape == render.ray_drop_prob.shape == (n,)
    keep = render.ray_drop_prob < 0.5
    expect = render.rays.origins.numpy()[keep] + render.rays.directions.numpy()[keep] * render.range[keep, None]
    np.testing.assert_allclose(render.points, expect, atol=1e-4)
    np.testing.assert_allclose(render.range, render.range_normalised * render.alpha, atol=1e-3)
    with torch.no_grad():  # a head that predicts every ray as returned: every metric is defined
        model.scene_model.lidar_head.mlp[-1].bias[1] = -20.0
    metrics = pipeline.get_average_eval_image_metrics(step=None)
    for key in ("lidar_depth_median_sq_err", "lidar_intensity_rmse", "lidar_raydrop_acc", "lidar_chamfer"):
        assert key in metrics and math.isfinite(metrics[key])
    assert 0.0 <= metrics["lidar_raydrop_acc"] <= 1.0
    assert metrics["lidar_num_sweeps"] == len(sweeps)


def test_camera_only_scene_has_no_lidar_head(tiny_street, tmp_path):
    trainer = _trainer(tiny_street, tmp_path, load_lidar=False)
    model = trainer.pipeline.model
    assert model.scene_model.lidar_head is None and model.lidar is None
    assert not any(k.startswith("lidar_head") for k in model.state_dict())
    assert "lidar_head" not in model.get_param_groups()
    losses = _step(trainer, 0)
    assert not any(k.startswith("lidar") for k in losses)
    assert trainer.pipeline._held_out_sweeps() == []


def test_lidar_disabled_by_config_gives_a_camera_only_model(tiny_street, tmp_path):
    trainer = _trainer(tiny_street, tmp_path, enabled=False)
    assert trainer.pipeline.model.scene_model.lidar_head is None
    assert not any(k.startswith("lidar") for k in _step(trainer, 0))


def test_camera_time_offsets_are_learnt_when_instances_move(tiny_street, tmp_path):
    trainer = _trainer(tiny_street, tmp_path, mode="oracle")
    sm = trainer.pipeline.model.scene_model
    assert sm.camera_time_offset is not None and sm.camera_time_offset.shape == (3,)
    assert torch.count_nonzero(sm.camera_time_offset) == 0  # zero-initialised
    assert trainer.pipeline.model.get_param_groups()["camera_time_offsets"] == [sm.camera_time_offset]
    # Moving cars are in view of some training images: their pixels depend on each camera's time.
    model = trainer.pipeline.model
    cameras = trainer.pipeline.datamanager.train_dataset.cameras
    model.eval()  # camera renders only (a training-mode render would add a lidar batch each)
    total = sum(model.get_outputs(cameras[i : i + 1])["rgb"].sum() for i in range(len(cameras)))
    total.backward()
    model.train()
    grad = sm.camera_time_offset.grad
    assert grad is not None and torch.isfinite(grad).all() and grad.abs().sum() > 0
