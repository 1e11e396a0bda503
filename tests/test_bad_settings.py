"""Bad settings never train silently (issue 25): each case sets one option out of its range and
asserts a one-line :class:`IDSplatError` naming the option, before any run folder is written; a
failed run removes the folders it created and nothing older. (Bad data: test_bad_input.py.)"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Callable

import pytest

from idsplat_ns.errors import IDSplatError, register_run_dir, remove_failed_runs


def _one_line(err: IDSplatError) -> str:
    msg = str(err)
    assert "\n" not in msg, f"multi-line error: {msg!r}"
    return msg


def _config():
    from method_configs.idsplat import idsplat_fast_method

    return copy.deepcopy(idsplat_fast_method.config)


def _with(obj, parts: list[str], value):
    """``obj`` with the value at ``parts`` replaced (frozen dataclasses rebuilt on the way up)."""
    key = parts[0]
    if len(parts) > 1:
        value = _with(obj[key] if isinstance(obj, dict) else getattr(obj, key), parts[1:], value)
    if isinstance(obj, dict):
        obj[key] = value
        return obj
    try:
        setattr(obj, key, value)
        return obj
    except dataclasses.FrozenInstanceError:
        return dataclasses.replace(obj, **{key: value})


def _apply(path: str, value) -> Callable:
    def edit(cfg) -> None:
        _with(cfg, path.split("."), value)
    return edit


SETTING_CASES = [
    ("downscale-zero", _apply("pipeline.datamanager.dataparser.downscale_factor", 0.0), "idsplat-auto --downscale-factor"),
    ("negative-lr", _apply("optimizers.means.optimizer.lr", -1e-3), "--optimizers.means.optimizer.lr"),
    ("nan-lr", _apply("optimizers.scales.optimizer.lr", float("nan")), "--optimizers.scales.optimizer.lr"),
    ("zero-eps", _apply("optimizers.quats.optimizer.eps", 0.0), "--optimizers.quats.optimizer.eps"),
    ("train-fraction-above-one", _apply("pipeline.datamanager.dataparser.train_fraction", 1.5), "--train-fraction"),
    ("start-after-end", lambda c: (_apply("pipeline.datamanager.dataparser.start_frame", 5)(c),
                                   _apply("pipeline.datamanager.dataparser.end_frame", 3)(c)), "--end-frame"),
    ("zero-iterations", _apply("max_num_iterations", 0), "--max-num-iterations"),
    ("lidar-every-zero-steps", _apply("pipeline.model.lidar.every_n_steps", 0), "--pipeline.model.lidar.every-n-steps"),
    ("ssim-lambda-above-one", _apply("pipeline.model.ssim_lambda", 2.0), "--pipeline.model.ssim-lambda"),
    ("negative-loss-weight", _apply("pipeline.model.lidar.losses.depth", -0.1), "--pipeline.model.lidar.losses.depth"),
    ("refine-start-after-stop", _apply("pipeline.model.mcmc.refine_start_iter", 10**6), "--pipeline.model.mcmc.refine-start-iter"),
    ("decreasing-resolution-schedule", _apply("pipeline.model.resolution_schedule", (700, 300)), "--pipeline.model.resolution-schedule"),
    ("negative-preprocess-sigma", _apply("pipeline.datamanager.preprocess.smoothing.motion_rot_sigma", -1.0),
     "--pipeline.datamanager.preprocess.smoothing.motion-rot-sigma"),
    ("dbscan-eps-zero", _apply("pipeline.datamanager.preprocess.lifting.dbscan_eps", 0.0), "--pipeline.datamanager.preprocess.lifting.dbscan-eps"),
    ("missing-import-tracks", _apply("pipeline.datamanager.import_tracks", Path("/nonexistent/tracks.json")), "--pipeline.datamanager.import-tracks"),
    ("camera-refinement-prior-zero-size", _apply("pipeline.model.camera_refinement_prior", (1e-3, 0.0, 0.05)),
     "--pipeline.model.camera-refinement-prior"),
    ("camera-refinement-prior-negative-weight", _apply("pipeline.model.camera_refinement_prior", (-1.0, 1.0, 0.05)),
     "--pipeline.model.camera-refinement-prior"),
    ("pose-refinement-prior-zero-size", _apply("pipeline.model.pose_refinement_prior", (1e-3, 0.5, 0.0)),
     "--pipeline.model.pose-refinement-prior"),
]


def test_default_settings_are_valid() -> None:
    from method_configs.idsplat import idsplat_fast_method, idsplat_method, idsplat_preview_method
    from idsplat_ns.nerfstudio import dataparser as dp
    from idsplat_ns.runs.settings_checks import validate_settings

    for method in (idsplat_method, idsplat_fast_method, idsplat_preview_method):
        validate_settings(method.config)
    for parser in (dp.AutoDataParserConfig, dp.BuiltinDataParserConfig, dp.PandaSetDataParserConfig, dp.WaymoDataParserConfig):
        cfg = _config()
        cfg.pipeline.datamanager.dataparser = parser()
        validate_settings(cfg)


def test_a_settings_range_travels_with_its_field() -> None:
    """The check is the one declared beside the field, whatever the field is called; a number
    without one must be finite and non-negative."""
    from idsplat_ns.ranges import UNIT, bounded
    from idsplat_ns.runs.settings_checks import validate_settings

    @dataclasses.dataclass
    class Inner:
        renamed_sigma: float = bounded(0.5, UNIT)  # a name that no rule could guess
        count: int = 3

    @dataclasses.dataclass
    class Outer:
        inner: Inner = dataclasses.field(default_factory=Inner)

    validate_settings(Outer(Inner(renamed_sigma=0.0)))  # in [0, 1], though a sigma of 0 would be refused by name
    for inner, words in ((Inner(renamed_sigma=1.5), "--inner.renamed-sigma 1.5: must be a number in [0, 1]"),
                         (Inner(count=-1), "--inner.count -1: must be a number in [0, inf)")):
        with pytest.raises(IDSplatError) as info:
            validate_settings(Outer(inner))
        assert words in _one_line(info.value)


@pytest.mark.parametrize("edit,option", [c[1:] for c in SETTING_CASES], ids=[c[0] for c in SETTING_CASES])
def test_bad_setting_fails_in_one_line(edit, option: str) -> None:
    from idsplat_ns.runs.settings_checks import validate_settings

    cfg = _config()
    edit(cfg)
    with pytest.raises(IDSplatError) as info:
        validate_settings(cfg)
    line = _one_line(info.value)
    assert option in line, line


def test_settings_are_checked_before_the_run_folder_is_written(tmp_path: Path) -> None:
    cfg = _config()
    cfg.output_dir = tmp_path / "outputs"
    cfg.optimizers["means"]["optimizer"].lr = -1.0
    with pytest.raises(IDSplatError):
        cfg.save_config()
    assert not cfg.output_dir.exists()


# --- Nothing left behind ---------------------------------------------------------------------------

def test_failed_run_folder_is_removed_unless_it_has_a_checkpoint(tmp_path: Path) -> None:
    root = tmp_path / "outputs"
    failed = root / "street" / "idsplat-fast" / "t1"
    kept = root / "street" / "idsplat-fast" / "t2"
    for run in (failed, kept):
        run.mkdir(parents=True)
        (run / "config.yml").write_text("x")
    (kept / "nerfstudio_models").mkdir()
    (kept / "nerfstudio_models" / "step-000000003.ckpt").write_text("x")
    register_run_dir(failed, root / "street")
    register_run_dir(kept, root / "street")
    assert remove_failed_runs() == [failed]
    assert not failed.exists() and kept.exists()
    register_run_dir(kept.parent / "t3", root)  # never created: nothing to do
    assert remove_failed_runs() == []


def test_a_failed_run_removes_the_output_folder_it_created_and_nothing_older(tmp_path: Path) -> None:
    from idsplat_ns.atomic import first_created

    older = tmp_path / "outputs" / "street" / "idsplat-fast" / "t0"
    older.mkdir(parents=True)
    for root, run in ((tmp_path / "new" / "deeper", "t1"), (tmp_path / "outputs", "t2")):
        run_dir = root / "street" / "idsplat-fast" / run
        created = first_created(run_dir)
        run_dir.mkdir(parents=True)
        (run_dir / "config.yml").write_text("x")
        register_run_dir(run_dir, created)
    assert len(remove_failed_runs()) == 2
    assert not (tmp_path / "new").exists()  # --output-dir new/deeper was made by the run: gone
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outputs"] and older.is_dir()


# --- Through the real command line ------------------------------------------------------------------
