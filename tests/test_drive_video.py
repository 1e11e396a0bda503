"""idsplat-render-drive (issue 21): the recorded drive of one camera re-rendered from a trained
run as a video, moving instances on their trained trajectories, optionally from a shifted viewpoint."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from idsplat_ns.errors import IDSplatError
from idsplat_ns.cli.render_drive import drive_order, recorded_frame_rate, shifted_camera_to_world


def test_shift_moves_the_camera_in_its_own_frame():
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("zyx", [40, -10, 5], degrees=True).as_matrix()
    c2w = np.concatenate([R, [[3.0], [-2.0], [1.5]]], 1)
    moved = shifted_camera_to_world(c2w, left=1.5, up=0.25)
    np.testing.assert_array_equal(moved[:, :3], R)  # same orientation
    # The new centre seen from the old camera (OpenGL axes: x right, y up): 1.5 m left, 0.25 m up.
    np.testing.assert_allclose(R.T @ (moved[:, 3] - c2w[:, 3]), [-1.5, 0.25, 0.0], atol=1e-12)


def test_drive_order_and_rate():
    cams = np.array([0, 1, 0, 0, 1])
    times = np.array([0.2, 0.0, 0.0, 0.1, 0.1])
    np.testing.assert_array_equal(drive_order(cams, times, 0), [2, 3, 0])
    np.testing.assert_array_equal(drive_order(cams, times, 1), [1, 4])
    assert recorded_frame_rate(np.array([0.0, 0.1, 0.2, 0.2, 0.35])) == pytest.approx(10.0)
    assert recorded_frame_rate(np.array([5.0])) == 10.0  # one image: no spacing to measure


@pytest.fixture(scope="module")
def pipeline(tiny_street, tmp_path_factory):
    pytest.importorskip("nerfstudio")
    sys.path.insert(0, str(Path(__file__).parent))
    from _tiny_run import loaded_pipeline, tiny_run

    return loaded_pipeline(tiny_run(tiny_street, tmp_path_factory))[0]


def test_video_holds_the_renders_and_the_recorded_images(pipeline, tmp_path):
    import cv2
    import torch

    from idsplat_ns.cli.render_drive import render_drive, write_frames

    camera = pipeline.model.camera_names[0]
    frames, rate = render_drive(pipeline, camera, (0.0, 0.0), 4, True, 3)
    assert len(frames) == 3 and rate > 0
    out = write_frames(frames, tmp_path / "v" / "drive.mp4", rate)
    capture = cv2.VideoCapture(str(out))  # OpenCV's own decoder, independent of the writer
    video = []
    while (got := capture.read())[0]:
        video.append(got[1][..., ::-1])  # BGR -> RGB
    video = np.stack(video)
    h, w = frames[0].shape[:2]
    assert video.shape[0] == 3 and video.shape[1] == h + h % 2 and video.shape[2] == w + w % 2
    assert not list(out.parent.glob(".*tmp*"))
    # The first frame is the first image of that camera, rendered directly, under the recorded one.
    ds = pipeline.datamanager.train_dataset
    meta = ds.cameras.metadata
    first = drive_order(meta["sensor_idx"].numpy(), meta["time_seconds"].numpy(), 0)[0]
    cam = ds.cameras[int(first) : int(first) + 1]
    cam.rescale_output_resolution(0.25)
    with torch.no_grad():
        direct = (pipeline.model.get_outputs_for_camera(cam)["rgb"].numpy() * 255).round()
    np.testing.assert_array_equal(frames[0][h // 2 :], direct.astype(np.uint8))
    assert np.abs(video[0, h // 2 : h, :w].astype(float) - direct).mean() < 6  # H.264 at mediapy's quality
    assert np.abs(frames[0][: h // 2].astype(float) - frames[0][h // 2 :]).mean() < 40  # a fit, not noise


def test_shifted_drive_as_png_frames(pipeline, tmp_path):
    from PIL import Image

    from idsplat_ns.cli.render_drive import render_drive, write_frames

    base, _ = render_drive(pipeline, None, (0.0, 0.0), 4, False, 1)
    moved, _ = render_drive(pipeline, None, (2.0, 0.0), 4, False, 1)
    assert np.abs(base[0].astype(float) - moved[0]).mean() > 2  # a new viewpoint, not the same picture
    folder = write_frames(moved, tmp_path / "frames", 10.0)
    np.testing.assert_array_equal(np.asarray(Image.open(folder / "frame_00000.png")), moved[0])


def test_bad_options_are_one_line(pipeline, tmp_path, capsys):
    from idsplat_ns.cli.render_drive import main, render_drive

    with pytest.raises(IDSplatError, match="--camera nope: not a camera of this run"):
        render_drive(pipeline, "nope", (0.0, 0.0), 4, False, 1)
    cfg = tmp_path / "config.yml"
    cfg.write_text("x")
    for argv, said in ((["--with-ground-truth", "--shift-left", "1"], "--with-ground-truth needs"),
                       (["--downscale", "0"], "--downscale must be"),
                       (["--load-config", str(tmp_path / "none.yml")], "no such file")):
        with pytest.raises(SystemExit) as exit_:
            main(["--load-config", str(cfg), "--output", str(tmp_path / "o.mp4"), *argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert exit_.value.code == 2 and len(err) == 1 and said in err[0]
