"""A Waymo v1 segment through the whole path: trained with the ``idsplat-waymo`` dataparser, then
loaded from its config.yml the way ``ns-eval``, ``ns-viewer`` and ``ns-render`` load a run. The
held-out evaluation runs, a recorded camera renders with its rolling shutter, and a camera without
a time (``ns-render interpolate``) renders too. The segment is the real frame of ../shared/data
re-framed into a short drive with lidar built by the fixtures (the real frame has no lidar)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

WAYMO_FRAME = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"
STEPS = 4

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not WAYMO_FRAME.is_file(), reason=f"real Waymo frame not found at {WAYMO_FRAME}")]


@pytest.fixture(scope="module")
def waymo_run(tmp_path_factory) -> Path:
    pytest.importorskip("nerfstudio")
    from method_configs.idsplat import make_trainer_config

    from idsplat_ns.data.waymo.fixtures import write_synthetic_segment
    from idsplat_ns.nerfstudio.dataparser import WaymoDataParserConfig

    tmp = tmp_path_factory.mktemp("waymo_run")
    segment = write_synthetic_segment(WAYMO_FRAME, tmp / "segment-1024360143612057520_3580_000_3600_000.tfrecord", 8,
                                      top_width=400)
    cfg = make_trainer_config("idsplat-fast", STEPS, (10**6, 10**6), fast=True)
    cfg.pipeline.datamanager.dataparser = WaymoDataParserConfig(data=segment, cameras=("FRONT", "FRONT_LEFT"),
                                                                lidars=("TOP",), downscale_factor=8.0)
    cfg.pipeline.datamanager.instance_mode = "oracle"  # the frame's 3D labels, re-framed with the drive
    cfg.pipeline.model.max_lidar_points = 8_000
    cfg.pipeline.model.num_random_points = 1_000
    cfg.vis = "tensorboard"
    cfg.output_dir = tmp / "out"
    cfg.steps_per_eval_image = 10**9
    cfg.set_timestamp()
    cfg.save_config()
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    return cfg.get_base_dir() / "config.yml"


def test_a_waymo_run_loads_evaluates_and_renders(waymo_run, capsys):
    from nerfstudio.utils.eval_utils import eval_setup

    config, pipeline, _, step = eval_setup(waymo_run, test_mode="test")
    assert step == STEPS - 1 and type(config.pipeline.datamanager.dataparser).__name__ == "WaymoDataParserConfig"
    model = pipeline.model
    assert model.camera_names == ["FRONT", "FRONT_LEFT"]

    metrics = pipeline.get_average_eval_image_metrics()  # what ns-eval writes
    assert metrics["num_images"] >= 2 and 0.0 < metrics["psnr"] < 60.0
    assert metrics["lidar_num_sweeps"] >= 1 and "lidar_raydrop_acc" in metrics  # Waymo has drop labels

    from idsplat_ns.nerfstudio.camera_read import read_camera

    camera = pipeline.datamanager.eval_dataset.cameras[0:1].to(model.device)
    # The recorded cameras render with their rolling shutter (Waymo's are rolling-shutter).
    assert model.shutters.has_rolling_shutter
    assert model.shutters.at(int(camera.metadata["sensor_idx"].reshape(-1)[0]), model._render_time(read_camera(camera))) is not None
    with torch.no_grad():
        out = model.get_outputs_for_camera(camera)
        assert out["rgb"].shape == (int(camera.height), int(camera.width), 3) and torch.isfinite(out["rgb"]).all()
        # ns-render interpolate: a camera with no time gets one from where it is on the drive.
        camera.times, camera.metadata = None, None
        capsys.readouterr()
        out = model.get_outputs_for_camera(camera)
        assert torch.isfinite(out["rgb"]).all() and "the camera path has no times" in capsys.readouterr().out
