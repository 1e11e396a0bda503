"""Rendering over time (issue 21): cameras without a time (ns-render's interpolated paths) are
placed in time along the recorded drive, with a one-time note, never rendered as a static-only
scene; ns-render without ffmpeg ends in one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.model.path_time import PathClock


def test_path_clock_interpolates_along_the_nearest_recorded_path():
    xs = np.arange(5.0)
    front = np.stack([xs * 10, np.zeros(5), np.zeros(5)], 1)  # 10 m per 0.1 s along +x
    side = front + [0.0, 50.0, 0.0]  # another sensor's path, far away, with other times
    clock = PathClock([front, side], [xs * 0.1, 100 + xs * 0.1])
    assert clock.time_of(np.array([25.0, 1.0, 0.5])) == pytest.approx(0.25)
    assert clock.time_of(np.array([-30.0, 0.0, 0.0])) == pytest.approx(0.0)  # before the start: clamped
    assert clock.time_of(np.array([10.0, 49.0, 0.0])) == pytest.approx(100.1)  # nearest is the other path
    assert PathClock([front[:1]], [np.array([3.0])]).time_of(np.ones(3)) == pytest.approx(3.0)


def test_ns_render_gets_the_installed_ffmpeg_when_the_system_has_none(tmp_path, monkeypatch):
    import shutil

    from idsplat_ns.nerfstudio.render_guard import check_render_tools

    monkeypatch.setenv("PATH", str(tmp_path))  # no system ffmpeg
    check_render_tools("/venv/bin/ns-eval")  # other commands do not need it
    assert shutil.which("ffmpeg") is None
    check_render_tools("/venv/bin/ns-render")
    found = shutil.which("ffmpeg")  # what nerfstudio's check and mediapy run
    assert found is not None and not found.startswith(str(tmp_path))
    res = subprocess.run([found, "-version"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.startswith("ffmpeg version")
    fake = tmp_path / "ffmpeg"  # a system ffmpeg is used as it is
    fake.write_text("#!/bin/sh\nexit 0\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", str(tmp_path))
    check_render_tools("/venv/bin/ns-render")
    assert shutil.which("ffmpeg") == str(fake)


def test_a_broken_install_without_imageio_ffmpeg_is_one_line(tmp_path, monkeypatch):
    from idsplat_ns._compat.ffmpeg import ensure_ffmpeg_on_path

    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails
    with pytest.raises(IDSplatError, match="imageio-ffmpeg cannot be imported"):
        ensure_ffmpeg_on_path()


@pytest.fixture(scope="module")
def pipeline(tiny_street, tmp_path_factory):
    pytest.importorskip("nerfstudio")
    sys.path.insert(0, str(Path(__file__).parent))
    from _tiny_run import loaded_pipeline, tiny_run

    return loaded_pipeline(tiny_run(tiny_street, tmp_path_factory))[0]


def _instance_pixels(pipeline, camera) -> torch.Tensor:
    with torch.no_grad():
        ids = pipeline.model.get_outputs_for_camera(camera)["instance_id"][..., 0]
    return ids > 0


def test_a_camera_without_time_is_rendered_at_its_place_in_the_drive(pipeline, capsys):
    from nerfstudio.cameras.cameras import Cameras

    cams = pipeline.datamanager.eval_dataset.cameras
    pipeline.model._noted_missing_time = False
    checked = 0
    for i in range(len(cams)):
        cam = cams[i : i + 1]
        with_time = _instance_pixels(pipeline, cam)
        if not bool(with_time.any()):
            continue
        bare = Cameras(camera_to_worlds=cam.camera_to_worlds, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy,
                       width=cam.width, height=cam.height, camera_type=cam.camera_type)  # no times, no metadata
        assert bare.times is None
        without = _instance_pixels(pipeline, bare)
        # Same instances in the same place: the camera's own sensor path passes exactly through it.
        assert float((with_time == without).float().mean()) > 0.99 and bool(without.any())
        checked += 1
        if checked == 2:
            break
    assert checked, "the tiny street shows moving vehicles in its eval images"
    notes = [ln for ln in capsys.readouterr().out.splitlines() if "no times" in ln]
    assert len(notes) == 1  # said once, on one line


def test_interpolated_path_shows_moving_vehicles(pipeline):
    from nerfstudio.cameras.camera_paths import get_interpolated_camera_path

    cams = pipeline.datamanager.eval_dataset.cameras
    path = get_interpolated_camera_path(cams[:3], steps=2, order_poses=False)  # 4 cameras, few renders
    assert path.times is None  # what ns-render interpolate gives the model
    frames = [bool(_instance_pixels(pipeline, path[i : i + 1].to(pipeline.device)).any()) for i in range(len(path))]
    assert len(frames) == 4 and sum(frames) >= 2, frames


@pytest.mark.slow
def test_ns_render_writes_a_video_without_a_system_ffmpeg(tiny_street, tmp_path_factory, tmp_path):
    import cv2

    sys.path.insert(0, str(Path(__file__).parent))
    from _tiny_run import tiny_run

    config = tiny_run(tiny_street, tmp_path_factory)
    bindir = Path(sys.executable).parent
    env = dict(os.environ, PATH=str(bindir), PYTHONWARNINGS="ignore")  # the venv only: no system ffmpeg
    out = tmp_path / "out.mp4"
    res = subprocess.run([str(bindir / "ns-render"), "interpolate", "--load-config", str(config), "--output-path",
                          str(out), "--pose-source", "eval", "--interpolation-steps", "1", "--downscale-factor", "4"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-2000:]
    capture = cv2.VideoCapture(str(out))
    assert capture.isOpened() and int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) >= 2
