"""Runs that survive a kill (issue 25): training resumes at the right step with the optimizer and
the grown Gaussians of its checkpoint; preprocessing killed and re-run writes the same cache."""

from __future__ import annotations

import filecmp
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from idsplat_ns.atomic import TMP_MARK
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.runs.checkpoints import DAMAGED_DIR, checkpoint_step, latest_complete, list_checkpoints

STEPS, SAVE_EVERY = 16, 8


def _config(data: Path, out: Path, name: str):
    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", STEPS, (10**6, 10**6), fast=True)
    cfg.pipeline.datamanager.dataparser.data = data
    cfg.pipeline.datamanager.instance_mode = "oracle"  # cheap instances: the test is about the trainer
    cfg.pipeline.model.max_lidar_points = 8_000
    cfg.pipeline.model.num_random_points = 2_000
    # MCMC grows the set before the checkpoint, so that loading it must reallocate the Gaussians.
    cfg.pipeline.model.mcmc.refine_start_iter = 2
    cfg.pipeline.model.mcmc.refine_every = 3
    cfg.steps_per_save = SAVE_EVERY
    cfg.save_only_latest_checkpoint = False
    cfg.steps_per_eval_image = 10**9
    cfg.vis = "tensorboard"
    cfg.output_dir = out
    cfg.experiment_name = name
    cfg.timestamp = "run"
    return cfg


def _trainer(cfg):
    from nerfstudio.scripts.train import _set_random_seed

    cfg.save_config()
    _set_random_seed(cfg.machine.seed)
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer


def _means(ckpt: Path) -> torch.Tensor:
    state = torch.load(ckpt, map_location="cpu", weights_only=False)["pipeline"]
    return next(v for k, v in state.items() if k.endswith("gaussians.means"))


def test_resume_restores_step_optimizer_and_gaussians(tiny_street: Path, tmp_path: Path) -> None:
    whole = _config(tiny_street, tmp_path, "whole")
    trainer = _trainer(whole)
    trainer.train()
    ckpts = sorted(whole.get_checkpoint_dir().glob("step-*.ckpt"))
    assert [checkpoint_step(p) for p in ckpts] == [SAVE_EVERY, STEPS - 1]
    middle = torch.load(ckpts[0], map_location="cpu", weights_only=True)  # as nerfstudio's eval_setup loads it
    grown = _means(ckpts[0]).shape[0]

    # The killed run: its folder holds the middle checkpoint only; the same config again resumes.
    resumed_cfg = _config(tiny_street, tmp_path, "resumed")
    folder = resumed_cfg.get_checkpoint_dir()
    folder.mkdir(parents=True)
    (folder / ckpts[0].name).write_bytes(ckpts[0].read_bytes())
    (folder / f"{ckpts[0].name}.tmp-123-deadbeef").write_bytes(b"half a checkpoint")  # a kill during a save
    trainer = _trainer(resumed_cfg)
    assert trainer._start_step == SAVE_EVERY + 1
    assert trainer.config.max_num_iterations == STEPS - SAVE_EVERY - 1  # the total stays the run's
    assert not list(folder.glob("*.tmp-*"))
    model = trainer.pipeline.model
    assert model.gaussians.num == grown
    groups = trainer.pipeline.get_param_groups()
    compared = 0
    for name, optimizer in trainer.optimizers.optimizers.items():
        held = optimizer.param_groups[0]["params"]
        assert all(a is b for a, b in zip(held, groups[name])), f"{name}: optimizer holds stale tensors"
        saved = middle["optimizers"][name]["state"]
        for index, param in enumerate(held):
            for key in ("exp_avg", "exp_avg_sq"):
                if index in saved and key in saved[index]:
                    assert torch.equal(optimizer.state[param][key], saved[index][key]), (name, key)
                    compared += 1
    assert compared >= 2 * len(GaussianSet.PARAM_NAMES), compared  # Adam's moments of every Gaussian group at least
    trainer.train()

    final = latest_complete(folder)
    assert checkpoint_step(final) == STEPS - 1
    moved = (_means(final)[:grown] - _means(ckpts[0])).abs().max().item()
    assert moved > 0, "the Gaussians did not train after the resume"
    # The uninterrupted run's result: the checkpoint kept every generator's state (camera order,
    # lidar rays, MCMC noise and relocations), so the resumed steps draw the same numbers.
    resumed, uninterrupted = _means(final), _means(ckpts[1])
    assert resumed.shape == uninterrupted.shape
    gap = (resumed - uninterrupted).abs().max().item()
    step_move = (resumed[:grown] - _means(ckpts[0])).abs().median().item()
    print(f"resume: largest |means gap| against the uninterrupted run {gap:.4g} m (median move since the middle {step_move:.4g} m)")
    assert gap <= 1e-6, gap


def _kill_when(proc: subprocess.Popen, ready, timeout: float) -> None:
    end = time.time() + timeout
    while time.time() < end and proc.poll() is None and not ready():
        time.sleep(0.05)
    assert proc.poll() is None, "the command ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def _bin(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


@pytest.mark.slow
def test_kill_during_training_then_the_resume_command(tiny_street: Path, tmp_path: Path) -> None:
    train = [_bin("ns-train"), "idsplat-fast", "--vis", "tensorboard", "--output-dir", str(tmp_path),
             "--experiment-name", "killed", "--timestamp", "run", "--max-num-iterations", "20",
             "--steps-per-save", "5", "--pipeline.model.num-random-points", "2000",
             "--pipeline.datamanager.instance-mode", "oracle", "--data", str(tiny_street)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    run = tmp_path / "killed" / "idsplat-fast" / "run"
    proc = subprocess.Popen(train, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    models = run / "nerfstudio_models"
    # Killed once the run keeps two checkpoints; then its newest is damaged (a copy cut short).
    _kill_when(proc, lambda: len(list_checkpoints(models)) >= 2, timeout=300)  # renamed only once read back
    newest, previous = list_checkpoints(models)[:2]
    before = checkpoint_step(previous)
    assert before < checkpoint_step(newest) < 19
    newest.write_bytes(newest.read_bytes()[:100])

    # The documented resume command: the run's own config. It resumes from the previous checkpoint.
    done = subprocess.run([_bin("ns-train"), "idsplat-fast", "--load-config", str(run / "config.yml")],
                          env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    said = " ".join(done.stdout.split())
    assert f"{newest.name}: unreadable checkpoint" in said and f"resuming from {previous.name} instead" in said, said[-2000:]
    assert f"(step {before}): {20 - before - 1} of 20 steps left" in said
    assert checkpoint_step(latest_complete(models)) == 19
    assert [checkpoint_step(p) for p in list_checkpoints(models)] == [19, 15]  # the newest two are kept
    assert (run / DAMAGED_DIR / newest.name).is_file()  # set aside, not deleted

    # The same command on the finished run trains nothing and ends cleanly.
    again = subprocess.run([_bin("ns-train"), "idsplat-fast", "--load-config", str(run / "config.yml")],
                           env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "nothing to train" in " ".join(again.stdout.split())
    assert checkpoint_step(latest_complete(run / "nerfstudio_models")) == 19


@pytest.mark.slow
def test_kill_during_preprocessing_then_rerun_gives_the_same_cache(tiny_street: Path, tmp_path: Path) -> None:
    command = [_bin("idsplat-preprocess"), "--data", str(tiny_street)]

    def results(cache: Path) -> list[Path]:
        while True:
            try:
                return sorted(p.relative_to(cache) for p in cache.rglob("*") if p.is_file() and TMP_MARK not in str(p))
            except FileNotFoundError:  # a stage renamed its temporary folder while this walked it: look again
                continue

    def run(cache: Path, kill: bool = False) -> None:
        env = {**os.environ, "IDSPLAT_CACHE": str(cache)}
        if not kill:
            subprocess.run(command, env=env, check=True, capture_output=True, timeout=600)
            return
        proc = subprocess.Popen(command, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _kill_when(proc, lambda: cache.is_dir() and bool(results(cache)), timeout=300)  # after the first stage

    run(tmp_path / "whole")
    whole = results(tmp_path / "whole")
    run(tmp_path / "killed", kill=True)
    assert 0 < len(results(tmp_path / "killed")) < len(whole)  # killed between stages' results
    run(tmp_path / "killed")
    killed = results(tmp_path / "killed")
    assert whole == killed and whole
    assert not [p for p in (tmp_path / "killed").rglob("*") if TMP_MARK in p.name]  # temporaries cleaned
    different = [p for p in whole if not filecmp.cmp(tmp_path / "whole" / p, tmp_path / "killed" / p, shallow=False)]
    assert not different, different
