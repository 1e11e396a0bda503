"""A tiny trained IDSplat run (oracle instances on the ``tiny`` street, a few training steps),
built once per test session and shared by the editing and export tests."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

STEPS = 10


@lru_cache(maxsize=1)
def _build(data: Path, out: Path) -> Path:
    from nerfstudio.scripts.train import _set_random_seed

    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", STEPS, (10**6, 10**6), fast=True)
    cfg.pipeline.datamanager.dataparser.data = data
    # Oracle tracks: cheap to rebuild at load time, and the IDs are those of the annotations.
    cfg.pipeline.datamanager.instance_mode = "oracle"
    cfg.pipeline.datamanager.dataparser.train_fraction = 0.8
    cfg.pipeline.model.max_lidar_points = 12_000
    cfg.pipeline.model.num_random_points = 3_000
    cfg.vis = "tensorboard"
    cfg.output_dir = out
    cfg.experiment_name = "tiny"
    cfg.steps_per_eval_image = 10**9
    cfg.set_timestamp()
    cfg.save_config()
    _set_random_seed(cfg.machine.seed)
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()  # saves the checkpoint of the last step, as ns-train does
    return cfg.get_base_dir() / "config.yml"


def tiny_run(tiny_street: Path, tmp_path_factory) -> Path:
    """config.yml of the shared tiny run."""
    return _build(Path(tiny_street), Path(tmp_path_factory.getbasetemp()) / "tiny_run")


@lru_cache(maxsize=1)
def _loaded(config: Path):
    from nerfstudio.utils.eval_utils import eval_setup

    _, pipeline, _, step = eval_setup(config, test_mode="test")
    return pipeline, step


def loaded_pipeline(config: Path):
    """(pipeline, step) of ``config`` loaded as ns-eval loads it (shared; restore what you change)."""
    return _loaded(Path(config))
