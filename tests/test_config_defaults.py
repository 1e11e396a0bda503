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
