"""The viewer end to end (issue 21): ``ns-viewer`` on the shared tiny run, opened in headless
Chromium. The screenshot shows the scene from the start view behind the ego (it matches a render
of that view by the model itself), and unticking an instance in the IDSplat panel removes it from
the picture where it was, and nowhere else.

Needs the Debian ``chromium`` package (no browser is downloaded); without it the test fails
with the install line."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("nerfstudio")

from _chromium import Chromium, chromium_path, free_port, wait_for_http  # noqa: E402

pytestmark = pytest.mark.slow

RESOLUTION = re.compile(r"Resolution: (\d+)x(\d+)px")
MAX_RES = 512  # nerfstudio's default "Max res": a finished (high-resolution) render has this side


@pytest.fixture(scope="module")
def chromium() -> str:
    """Chromium's path; fails at once, before any training, with the install line when missing."""
    return chromium_path()


@pytest.fixture(scope="module")
def run_config(tiny_street, tmp_path_factory):
    from _tiny_run import tiny_run

    return tiny_run(tiny_street, tmp_path_factory)


def _reference(pipeline, width: int, height: int) -> dict:
    """The model's own render of the viewer's start view at the canvas size, at the first frame."""
    from nerfstudio.cameras.cameras import Cameras, CameraType

    from idsplat_ns.nerfstudio.dataparser import OPENCV_TO_OPENGL

    model = pipeline.model
    view = model.viewer_controls.start
    c2w = view.camera_to_world() @ OPENCV_TO_OPENGL
    focal = 0.5 * height / math.tan(0.5 * view.fov_y)
    camera = Cameras(camera_to_worlds=torch.tensor(c2w[None, :3, :4], dtype=torch.float32), fx=focal, fy=focal,
                     cx=width / 2, cy=height / 2, width=width, height=height, camera_type=CameraType.PERSPECTIVE,
                     times=torch.zeros(1, 1))
    with torch.no_grad():
        out = model.get_outputs_for_camera(camera)
    return {k: v.cpu().numpy() for k, v in out.items() if k in ("rgb", "instance_id")}


def _grey_small(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:  # [H, W, 3] -> [h, w] float
    from PIL import Image

    if image.dtype != np.uint8:
        image = (np.clip(image, 0, 1) * 255).astype(np.uint8)
    return np.asarray(Image.fromarray(image).convert("L").resize(size, Image.BOX), dtype=np.float64)


def _nearest(ids: np.ndarray, size: tuple[int, int]) -> np.ndarray:  # [h, w] -> [H, W] int
    from PIL import Image

    return np.asarray(Image.fromarray(ids).resize(size, Image.NEAREST)).astype(int)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


CANVAS_BOX = ("(() => { const r = document.querySelector('canvas[data-engine^=\"three.js\"]').getBoundingClientRect();"
              " return [Math.ceil(r.left), Math.ceil(r.top), Math.floor(r.right), Math.floor(r.bottom)]; })()")


def _finished_render(page: Chromium, timeout: float, unlike: np.ndarray | None = None) -> tuple[np.ndarray, tuple]:
    """The 3D canvas (crop [H, W, 3] int16, box) once a full-resolution render shows and stays (two
    screenshots 1 s apart are the same, the canvas has not moved), and, with ``unlike``, once it
    is no longer that picture."""
    deadline = time.time() + timeout
    previous, previous_box = None, None
    while time.time() < deadline:
        found = RESOLUTION.search(page.js("document.body.innerText") or "")
        x0, y0, x1, y1 = box = tuple(page.js(CANVAS_BOX))
        crop = page.screenshot()[y0:y1, x0:x1].astype(np.int16)
        full = found is not None and max(int(found.group(1)), int(found.group(2))) == MAX_RES
        changed = unlike is None or crop.shape != unlike.shape or np.abs(crop - unlike).mean() > 0.5
        if full and changed and box == previous_box and np.abs(crop - previous).max() <= 2:
            return crop, box
        previous, previous_box = crop, box
        time.sleep(1.0)
    raise AssertionError(f"no finished render in the viewer within {timeout:.0f} s")


def _click_label(page: Chromium, label: str) -> None:
    """Click the input of the panel row labelled ``label`` (viser: <label for=input-id>)."""
    clicked = page.js(f"""(() => {{
        const l = [...document.querySelectorAll('label')].find(e => e.textContent.trim() === {label!r});
        if (!l) return false;
        document.getElementById(l.htmlFor).click();
        return true; }})()""")
    assert clicked, f"no control labelled {label!r} in the viewer panel"


def test_viewer_renders_the_scene_and_hiding_an_instance_removes_it(chromium, run_config, tmp_path):
    from scipy.ndimage import binary_dilation

    from _tiny_run import loaded_pipeline

    port = free_port()
    log = tmp_path / "ns-viewer.log"
    ns_viewer = Path(sys.executable).with_name("ns-viewer")
    with open(log, "w") as out:
        # No training-camera frustums: only the render (and the panel's drawings) in the picture.
        proc = subprocess.Popen([str(ns_viewer), "--load-config", str(run_config), "--viewer.websocket-port", str(port),
                                 "--viewer.websocket-host", "127.0.0.1", "--viewer.max-num-display-images", "0"],
                                stdout=out, stderr=subprocess.STDOUT)
    try:
        pipeline, _ = loaded_pipeline(run_config)  # while ns-viewer starts
        url = f"http://127.0.0.1:{port}"
        wait_for_http(url, proc, log, timeout=180)
        with Chromium(1200, 800) as page:
            page.call("Emulation.setDeviceMetricsOverride", width=1200, height=800, deviceScaleFactor=1, mobile=False)
            page.open(url)
            page.wait_for("document.body.innerText.includes('Static background')", 90, "the IDSplat panel")
            _click_label(page, "Trajectories")  # no paths, markers or labels over the render
            before, box = _finished_render(page, timeout=120)
            height, width = before.shape[:2]  # the canvas inside the window
            page.save(before.astype(np.uint8), tmp_path / "before.png")

            reference = _reference(pipeline, width // 4, height // 4)  # a quarter: enough, and quick
            small = (width // 8, height // 8)
            shot, ref = _grey_small(before.astype(np.uint8), small), _grey_small(reference["rgb"], small)
            assert shot.std() > 10, f"the viewer's picture is nearly uniform (std {shot.std():.1f}): {tmp_path}"
            corr = _correlation(shot, ref)
            assert corr > 0.8, f"the viewer does not show the start view (correlation {corr:.2f}): {tmp_path}"

            ids = _nearest(reference["instance_id"][..., 0].round().astype(np.int32), (width, height))
            shown = [int(i) for i in np.unique(ids) if i > 0]
            assert shown, "no instance in the start view of the tiny street"
            target = max(shown, key=lambda i: int((ids == i).sum()))
            mask = ids == target
            assert mask.mean() > 0.005, f"instance {target} covers only {mask.mean():.2%} of the view"
            _click_label(page, f"ID {target}")
            after, after_box = _finished_render(page, timeout=120, unlike=before)
            assert after_box == box, "the viewer's canvas moved"
            page.save(after.astype(np.uint8), tmp_path / "after.png")
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()

    diff = np.abs(after - before).mean(-1)  # [height, width] grey levels
    near = binary_dilation(mask, iterations=25)  # the decoder CNN and JPEG spread an edit a little
    inside, outside = float(diff[mask].mean()), float(diff[~near].mean())
    print(f"start view correlation {corr:.3f}; hiding instance {target} ({mask.mean():.1%} of the view) changed "
          f"its pixels by {inside:.1f} and the rest by {outside:.1f} grey levels")
    assert inside > 10 and inside > 5 * outside, (
        f"hiding instance {target} changed its pixels by {inside:.1f} and the rest by {outside:.1f} grey levels: {tmp_path}")
