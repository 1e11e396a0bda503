"""Per-image colour correction (issue 45): the interpolation against numpy's, identity at zero,
gradients only to the knots in use, a checkpoint round trip, drifting gains recovered from images,
and a run trained with it (and the camera refinement) that ns-eval's loader reloads."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from idsplat_ns.model.camera_knots import interpolation_weights
from idsplat_ns.model.exposure import ImageExposure


def test_interpolation_is_numpys_with_clamped_ends() -> None:
    rng = np.random.default_rng(0)
    knots = np.sort(rng.uniform(0, 4, 7))
    values = rng.normal(size=7)
    for t in np.concatenate([rng.uniform(-1, 5, 50), knots]):
        i, j, w = interpolation_weights(knots, float(t))
        assert (1 - w) * values[i] + w * values[j] == pytest.approx(np.interp(t, knots, values), abs=1e-12)
    assert interpolation_weights(np.array([2.0]), 9.0) == (0, 0, 0.0)


def test_identity_at_start_and_gradients_reach_only_the_knots_in_use() -> None:
    exposure = ImageExposure([np.array([0.0, 0.1, 0.2]), np.array([]), np.array([0.05])])
    rgb = torch.rand(4, 5, 3)
    assert torch.equal(exposure(rgb, 0, 0.13), rgb)
    assert exposure(rgb, 1, 0.1) is rgb  # a camera without training images: as rendered
    assert exposure(rgb, 0, None) is rgb  # no time (a static scene's camera path)
    exposure(rgb, 0, 0.1).sum().backward()  # a training image: its own transform alone
    touched = exposure.affine.grad.abs().sum((1, 2)) > 0
    assert touched.tolist() == [False, True, False, False]
    exposure.affine.grad = None
    exposure(rgb, 0, 0.15).sum().backward()  # a held-out time between two training images
    assert (exposure.affine.grad.abs().sum((1, 2)) > 0).tolist() == [False, True, True, False]


def test_a_checkpoint_brings_its_own_knots() -> None:
    exposure = ImageExposure([np.array([0.3, 0.1, 0.1]), np.array([0.2])])
    with torch.no_grad():
        exposure.affine.normal_()
    state = {f"exposure.{k}": v for k, v in exposure.state_dict().items()}
    again = ImageExposure.like(state, "exposure.")
    again.load_state_dict(exposure.state_dict())
    assert torch.equal(again.times, torch.tensor([0.1, 0.3, 0.2], dtype=torch.float64))  # repeats: one knot
    rgb = torch.rand(2, 2, 3)
    assert torch.equal(again(rgb, 0, 0.2), exposure(rgb, 0, 0.2))


def test_drifting_gains_are_recovered_and_held_out_frames_interpolated() -> None:
    """Images of one scene under a smooth gain drift: the transforms fitted on every other frame
    give the held-out frames their gain to within the drift's curvature."""
    torch.manual_seed(0)
    times = np.arange(20) / 10.0
    gains = 1.0 + 0.3 * np.sin(2 * np.pi * times / 2.0)
    scene = torch.rand(16, 16, 3) * 0.7
    train = times[::2]
    exposure = ImageExposure([train])
    opt = torch.optim.Adam(exposure.parameters(), lr=0.02)
    for _ in range(400):
        opt.zero_grad()
        loss = sum((exposure(scene, 0, float(t)) - scene * g).abs().mean() for t, g in zip(times[::2], gains[::2]))
        loss.backward()
        opt.step()
    with torch.no_grad():
        fitted = [float((exposure(scene, 0, float(t)) / scene).median()) for t in times]
    trained_err = np.abs(np.array(fitted[::2]) - gains[::2]).max()
    held_err = np.abs(np.array(fitted[1:-1:2]) - gains[1:-1:2]).max()  # between two training frames
    print(f"gain error: training frames {trained_err:.4f}, held-out frames {held_err:.4f}")
    assert trained_err < 0.01
    assert held_err < 0.01 + 0.3 * (1 - np.cos(np.pi / 10))  # fit + linear interpolation of the sine
    assert fitted[-1] == pytest.approx(fitted[-2], abs=1e-6)  # after the last training frame: its transform


def test_the_generator_drifts_exposure_only_when_asked() -> None:
    from idsplat_ns.data.synthetic.cli import config_from_args
    from idsplat_ns.data.synthetic.config import config_to_dict, exposure_gain, get_preset

    assert "exposure_drift" not in config_to_dict(get_preset("small"))["cameras"]  # old streets stay cache hits
    config = config_from_args("small", None, None, exposure_drift=0.3)
    assert config.name == "small_ex0.3" and config.cameras.exposure_drift == 0.3
    duration = config.num_frames / config.frame_rate
    gains = np.array([[exposure_gain(config.cameras, c, t, duration) for t in np.linspace(0, duration, 200)] for c in range(3)])
    assert gains.min() == pytest.approx(0.7, abs=1e-3) and gains.max() == pytest.approx(1.3, abs=1e-3)
    assert not np.allclose(gains[0], gains[1])  # its own phase per camera


@pytest.mark.slow
def test_a_run_with_every_sensor_correction_trains_and_reloads(tiny_street, tmp_path) -> None:
    """Exposure, calibration and per-image pose corrections in one tiny run
    (tests/test_camera_refinement.py has the poses' maths)."""
    from nerfstudio.scripts.train import _set_random_seed
    from nerfstudio.utils.eval_utils import eval_setup

    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", 6, (10**6, 10**6), fast=True)
    cfg.pipeline.datamanager.dataparser.data = tiny_street
    cfg.pipeline.datamanager.instance_mode = "oracle"
    cfg.pipeline.model.exposure = True
    cfg.pipeline.model.camera_refinement = True
    cfg.pipeline.model.pose_refinement = True
    cfg.pipeline.model.num_random_points = 2_000
    cfg.vis, cfg.output_dir, cfg.timestamp, cfg.steps_per_eval_image = "tensorboard", tmp_path, "run", 10**9
    cfg.save_config()
    _set_random_seed(cfg.machine.seed)
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    exposure, rig = trainer.pipeline.model.exposure, trainer.pipeline.model.rig_correction
    assert exposure is not None and float(exposure.affine.abs().sum()) > 0  # it learned something
    assert rig is not None and float(rig.rotation.abs().sum()) > 0
    poses = trainer.pipeline.model.pose_correction
    assert poses is not None and float(poses.translation.abs().sum()) > 0
    _, pipeline, _, _ = eval_setup(cfg.get_base_dir() / "config.yml", test_mode="test")
    assert torch.equal(pipeline.model.exposure.affine.cpu(), exposure.affine.detach().cpu())
    assert torch.equal(pipeline.model.rig_correction.rotation.cpu(), rig.rotation.detach().cpu())
    assert torch.equal(pipeline.model.pose_correction.translation.cpu(), poses.translation.detach().cpu())
    assert torch.equal(pipeline.model.pose_correction.times.cpu(), poses.times.cpu())
    metrics = pipeline.get_average_eval_image_metrics()
    assert np.isfinite(metrics["psnr"])
    learned = metrics["camera_corrections"]  # ns-eval's JSON: per camera, what each correction learned
    assert set(learned) == set(pipeline.model.camera_names)
    assert learned["front_camera"]["calibration_deg"] == pytest.approx(rig.summary()[0][0])
    assert learned["front_camera"]["image_pose_median_m"] == pytest.approx(poses.summary()[0][1])


def test_smoothness_is_the_gap_to_the_neighbours_interpolation() -> None:
    """Against a loop over each camera's knots: zero for transforms linear in time, whatever the
    spacing; the square of the offset from the neighbours' line otherwise; no term at the ends."""
    rng = np.random.default_rng(1)
    cams = [np.sort(rng.uniform(0, 3, 6)), np.array([0.5, 1.0]), np.sort(rng.uniform(0, 3, 4))]
    exposure = ImageExposure(cams)
    with torch.no_grad():  # linear in time per camera: nothing to pay
        slope, start = torch.randn(3, 3, 4), torch.randn(3, 3, 4)
        exposure.affine.copy_(torch.cat([start[c] + slope[c] * torch.as_tensor(np.sort(np.unique(t)), dtype=torch.float32)[:, None, None]
                                         for c, t in enumerate(cams)]))
    assert float(exposure.smoothness()) == pytest.approx(0.0, abs=1e-10)
    with torch.no_grad():
        exposure.affine.normal_()
    values, times, offset, gaps = exposure.affine.detach().numpy(), exposure.times.numpy(), 0, []
    for t in cams:
        for i in range(offset + 1, offset + len(t) - 1):
            w = (times[i] - times[i - 1]) / (times[i + 1] - times[i - 1])
            gaps.append(values[i] - ((1 - w) * values[i - 1] + w * values[i + 1]))
        offset += len(t)
    assert float(exposure.smoothness()) == pytest.approx(float(np.mean(np.square(gaps))), rel=1e-5)
    exposure.smoothness().backward()
    assert exposure.affine.grad[6:8].abs().sum() == 0  # the two-image camera has no middle knot
    assert float(ImageExposure([np.array([0.1, 0.2])]).smoothness()) == 0.0
