"""A run folder written before a setting existed still loads: its config.yml lacks the field, and
the loaded config has the field's default (ns-eval, ns-viewer and ns-render read config.yml)."""

from __future__ import annotations

import dataclasses

import pytest
import yaml

pytest.importorskip("nerfstudio")


def _config():
    from method_configs.idsplat import make_trainer_config

    return make_trainer_config("idsplat-fast", 10, (1, 2), fast=True)


def test_a_config_without_newer_settings_loads_with_their_defaults():
    cfg = _config()
    model = cfg.pipeline.model
    del model.__dict__["deformation"]  # a nested config, as a version before it would write
    del model.__dict__["view_directions"]
    del model.lidar.__dict__["every_n_steps"]
    del cfg.pipeline.datamanager.preprocess.smoothing.__dict__["degenerate_one_sided"]
    text = yaml.dump(cfg)
    assert "DeformationConfig" not in text and "view_directions" not in text and "degenerate_one_sided" not in text
    loaded = yaml.load(text, Loader=yaml.Loader)  # what nerfstudio's eval_setup does
    fresh = _config()
    assert loaded.pipeline.model.deformation == fresh.pipeline.model.deformation
    assert loaded.pipeline.model.view_directions is True
    default = {f.name: f.default for f in dataclasses.fields(type(model.lidar))}["every_n_steps"]
    assert loaded.pipeline.model.lidar.every_n_steps == default
    assert loaded.pipeline.datamanager.preprocess.smoothing.degenerate_one_sided is True


def test_a_complete_config_round_trips_unchanged():
    cfg = _config()
    text = yaml.dump(cfg)
    assert yaml.dump(yaml.load(text, Loader=yaml.Loader)) == text


def _bench_pareto():
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("pareto", Path(__file__).resolve().parents[1] / "bench" / "pareto.py")
    pareto = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pareto)
    return pareto


def test_the_cpu_presets_are_the_points_measured_in_bench_pareto():
    # docs/pareto.md reports the CPU presets as points of bench/pareto.py: the
    # presets must be what those points train.
    from method_configs.idsplat import idsplat_fast_method, idsplat_medium_method, idsplat_preview_method

    pareto = _bench_pareto()
    for method, point in ((idsplat_fast_method, "steps-1500 (idsplat-fast)"),
                          (idsplat_medium_method, "steps-3000 (idsplat-medium)"),
                          (idsplat_preview_method, "steps-1000, half initial Gaussians")):  # fmt: skip
        cfg = pareto.point_config(*pareto.POINTS[point])
        assert cfg.max_num_iterations == method.config.max_num_iterations
        assert cfg.pipeline.model == method.config.pipeline.model
        assert cfg.optimizers == method.config.optimizers


def test_bench_pareto_children_run_on_the_threads_asked(capsys):
    # docs/pareto.md reports CPU times of one-thread trainings: the count reaches the child.
    import os
    import sys

    pareto = _bench_pareto()
    probe = "import torch; print('THREADS', torch.get_num_threads())"
    for threads in (1, 2):
        assert pareto.measured([sys.executable, "-c", probe], threads)["rc"] == 0
        assert f"THREADS {min(threads, os.cpu_count())}" in capsys.readouterr().out  # torch takes at most the cores
