"""nerfstudio dataparsers: cameras in nerfstudio's convention agree with the scene's camera model."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from idsplat_ns.nerfstudio.model_inputs import split_data

pytest.importorskip("nerfstudio")


def _ray_through(cameras, idx: int, uv: np.ndarray):
    """nerfstudio's own ray generation through pixel coordinates uv [N, 2] of camera idx."""
    coords = torch.from_numpy(uv[:, ::-1].copy()).float()  # nerfstudio wants (row, col)
    bundle = cameras.generate_rays(camera_indices=idx, coords=coords)
    return bundle.origins.numpy().astype(np.float64), bundle.directions.numpy().astype(np.float64)


def test_pandaset_dataparser_cameras_match_scene_projection(tiny_street):
    from idsplat_ns.nerfstudio.dataparser import PandaSetDataParserConfig

    parser = PandaSetDataParserConfig(data=tiny_street, train_fraction=0.5).setup()
    train = parser.get_dataparser_outputs("train")
    test = parser.get_dataparser_outputs("test")
    scene = split_data(train.metadata).scene
    n_train, n_test = len(train.image_filenames), len(test.image_filenames)
    assert n_train + n_test == len(scene.images) and n_test > 0
    assert {im.frame_index for im in split_data(train.metadata).images}.isdisjoint({im.frame_index for im in split_data(test.metadata).images})
    # A lidar point seen by a camera: nerfstudio's ray through our projected pixel must pass through it.
    image = split_data(train.metadata).images[4]
    idx = 4
    pts = scene.lidar[0].points
    proj = image.project(pts)
    sel = np.nonzero(proj.valid & (proj.depth > 3))[0][:20]
    assert len(sel) > 5
    o, d = _ray_through(train.cameras, idx, proj.uv[sel])
    to_point = pts[sel] - o
    along = np.sum(to_point * d, 1)
    miss = np.linalg.norm(to_point - along[:, None] * d, axis=1)
    assert np.all(along > 0) and np.max(miss / along) < 2e-3  # float32 cameras: sub-pixel angles
    sensor = train.cameras.metadata["sensor_idx"][:, 0].tolist()
    assert sensor[:3] == [0, 1, 2] and max(sensor) == 2


def test_pandaset_downscale_and_camera_subset(tiny_street):
    from idsplat_ns.nerfstudio.dataparser import PandaSetDataParserConfig

    parser = PandaSetDataParserConfig(data=tiny_street, cameras=("front_camera",), downscale_factor=2).setup()
    out = parser.get_dataparser_outputs("train")
    full = split_data(out.metadata).scene.images[0].intrinsics
    assert int(out.cameras.width[0]) == full.width // 2 and float(out.cameras.fx[0]) == pytest.approx(full.fx / 2, rel=1e-2)
    assert set(out.cameras.metadata["sensor_idx"][:, 0].tolist()) == {0}


def test_waymo_dataparser_on_the_real_frame(shared_data):
    from idsplat_ns.nerfstudio.dataparser import WaymoDataParserConfig
    from idsplat_ns.nerfstudio.dataset import IDSplatDataset

    cfg = WaymoDataParserConfig(data=shared_data / "waymo" / "pvps_data_one_frame.tfrecord", cameras=("FRONT",),
                                downscale_factor=4, eval_every=None, train_fraction=1.0)  # one frame: train on it
    out = cfg.setup().get_dataparser_outputs("train")
    assert len(out.image_filenames) == 1 and int(out.cameras.width[0]) == 480 and int(out.cameras.height[0]) == 320
    image = split_data(out.metadata).images[0]
    assert not image.intrinsics.has_distortion and "undistort_from" in image.metadata
    pixels = IDSplatDataset(out).get_numpy_image(0)
    assert pixels.shape == (320, 480, 3) and pixels.mean() > 20
