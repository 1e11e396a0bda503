"""End to end through nerfstudio: train the static model on the tiny street, evaluate held-out frames."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("nerfstudio")

REPO = Path(__file__).resolve().parents[1]
STEPS = 300


def _config(data: Path, out: Path, steps: int):
    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", steps, (steps // 6, steps // 3), fast=True)
    cfg.pipeline.datamanager.dataparser.data = data
    cfg.pipeline.model.max_lidar_points = 12_000
    cfg.pipeline.model.num_random_points = 3_000
    cfg.vis = "tensorboard"
    cfg.output_dir = out
    cfg.steps_per_eval_image = 10**9
    cfg.set_timestamp()
    return cfg


@pytest.mark.slow
def test_training_raises_held_out_psnr(tiny_street, tmp_path):
    cfg = _config(tiny_street, tmp_path, STEPS)
    cfg.save_config()  # what ns-train does before training; ns-eval and ns-viewer load this file
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    before = trainer.pipeline.get_average_eval_image_metrics(step=0)
    trainer.train()
    after = trainer.pipeline.get_average_eval_image_metrics(step=STEPS)
    print(f"held-out PSNR {before['psnr']:.2f} -> {after['psnr']:.2f} dB, SSIM {before['ssim']:.3f} -> {after['ssim']:.3f}, "
          f"DPSNR {before.get('dpsnr', float('nan')):.2f} -> {after.get('dpsnr', float('nan')):.2f} dB")
    assert after["psnr"] > before["psnr"] + 3.0
    assert after["ssim"] > before["ssim"]
    assert "dpsnr" in after and after["dpsnr_num_images"] >= 1  # the tiny street has moving cars in view
    ckpts = list((tmp_path / "unnamed" / "idsplat-fast").glob("*/nerfstudio_models/*.ckpt"))
    assert ckpts, "training must write a checkpoint"

    # The checkpoint reloads the way ns-eval / ns-viewer load it and renders the same numbers.
    from nerfstudio.utils.eval_utils import eval_setup

    config_path = next((tmp_path / "unnamed" / "idsplat-fast").glob("*/config.yml"))
    _, pipeline, _, step = eval_setup(config_path, test_mode="test")
    reloaded = pipeline.get_average_eval_image_metrics()
    assert step == STEPS - 1
    assert reloaded["psnr"] == pytest.approx(after["psnr"], abs=1e-3)
    assert "lpips_note" in reloaded  # no backbone given: a note, not a crash or a download


def _run(args: list[str], **kw) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run(args, capture_output=True, text=True, timeout=120, env=env, **kw)


def test_ns_train_lists_idsplat():
    ns_train = Path(sys.executable).parent / "ns-train"
    res = _run([str(ns_train), "--help"])
    assert res.returncode == 0
    for method in ("idsplat", "idsplat-fast", "idsplat-preview", "idsplat-medium"):
        assert method in res.stdout, method


def test_ns_train_missing_data_is_one_line(tmp_path):
    ns_train = Path(sys.executable).parent / "ns-train"
    res = _run([str(ns_train), "idsplat", "--data", "/nonexistent", "--vis", "tensorboard",
                "--output-dir", str(tmp_path)], cwd=tmp_path)
    assert res.returncode == 2, res.stderr[-2000:]
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "/nonexistent" in lines[0] and "--data" in lines[0]


def test_truncated_pickle_is_one_line_through_ns_train(tiny_street, tmp_path):
    import shutil

    seq = tmp_path / "broken"
    shutil.copytree(tiny_street, seq)
    pkl = seq / "lidar" / "03.pkl.gz"
    pkl.write_bytes(pkl.read_bytes()[:100])
    ns_train = Path(sys.executable).parent / "ns-train"
    res = _run([str(ns_train), "idsplat", "--data", str(seq), "--vis", "tensorboard", "--output-dir", str(tmp_path / "out")])
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert f"error: {pkl}: unreadable pickle" in res.stderr


def test_synth_cli_bad_preset_is_one_line(tmp_path):
    synth = Path(sys.executable).parent / "idsplat-synth"
    res = _run([str(synth), "--preset", "huge", "--out", str(tmp_path)])
    assert res.returncode == 2 and "Traceback" not in res.stderr
    errors = [ln for ln in res.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and "huge" in errors[0]
