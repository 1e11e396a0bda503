"""The README's commands on the kind of run ``make demo`` makes: trained on the built-in street,
whose config has no ``--data`` (issue 46: ``ns-viewer`` once failed on exactly that).

One small run (the ``tiny`` built-in street, a few steps) goes through ``ns-viewer`` (a real
process, until it serves its page), ``ns-render dataset``, ``idsplat-edit`` and
``idsplat-render-drive``, and the edited run through ``ns-eval``'s loader.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("nerfstudio")

from _chromium import free_port, wait_for_http  # noqa: E402

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def builtin_run(tmp_path_factory) -> Path:
    from nerfstudio.scripts.train import _set_random_seed

    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", 5, (10**6, 10**6), fast=True)
    cfg.pipeline.datamanager.dataparser.builtin_preset = "tiny"  # no --data: the built-in street, as make demo
    cfg.pipeline.datamanager.instance_mode = "oracle"
    cfg.pipeline.model.num_random_points = 2_000
    cfg.vis = "tensorboard"
    cfg.output_dir = tmp_path_factory.mktemp("builtin_run")
    cfg.experiment_name = "demo"
    cfg.timestamp = "run"
    cfg.steps_per_eval_image = 10**9
    cfg.save_config()
    _set_random_seed(cfg.machine.seed)
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    assert cfg.pipeline.datamanager.dataparser.data is None
    return cfg.get_base_dir() / "config.yml"


def test_ns_viewer_serves_a_builtin_street_run(builtin_run: Path, tmp_path: Path) -> None:
    port = free_port()
    log = tmp_path / "ns-viewer.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([str(Path(sys.executable).with_name("ns-viewer")), "--load-config", str(builtin_run),
                                 "--viewer.websocket-port", str(port), "--viewer.websocket-host", "127.0.0.1"],
                                stdout=out, stderr=subprocess.STDOUT)
    try:
        wait_for_http(f"http://127.0.0.1:{port}", proc, log, timeout=180)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
    assert "Traceback" not in log.read_text()


def test_ns_render_edit_and_drive_on_a_builtin_street_run(builtin_run: Path, tmp_path: Path) -> None:
    from nerfstudio.scripts.render import DatasetRender
    from nerfstudio.utils.eval_utils import eval_setup

    from idsplat_ns.cli import edit, render_drive

    # ns-render dataset: every output it writes must be an image (a colour vector once was not).
    DatasetRender(load_config=builtin_run, output_path=tmp_path / "renders").main()
    split = tmp_path / "renders" / "test"
    written = {p.relative_to(split).parts[0] for p in split.rglob("*.*")}  # <output>/<camera>/<image>
    assert {"rgb", "gt-rgb", "depth", "instances"} <= written, written

    edit.main(["--load-config", str(builtin_run), "--output-dir", str(tmp_path / "edited"), "--remove", "1"])
    edited = tmp_path / "edited" / "config.yml"
    _, pipeline, _, _ = eval_setup(edited, test_mode="test")  # as ns-eval and ns-viewer load it
    assert 1 not in pipeline.model.scene_model.trajectories.instance_ids.tolist()
    assert pipeline.datamanager.get_datapath().is_dir()  # what ns-viewer opens

    render_drive.main(["--load-config", str(edited), "--output", str(tmp_path / "frames"), "--max-frames", "2"])
    assert len(list((tmp_path / "frames").glob("frame_*.png"))) == 2
