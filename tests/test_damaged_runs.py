"""Damaged and foreign runs given to every command that loads a trained run (issue 46).

Each command gets a copy of the shared tiny run with: no checkpoint, the checkpoint truncated (to
0 and to 100 bytes), only the newest of two checkpoints truncated, the config.yml of another
method, and a data folder that has moved. Each case ends in one line naming the file, or, where
the command needs no data or an earlier checkpoint loads, succeeds. The commands run in this
process (their imports are shared: seconds, not minutes); their one-line ends are what the
excepthook prints (:func:`idsplat_ns.errors.one_line` with the translators that
``method_configs`` installs); two cases go through the real entry points to check that wiring.
"""

from __future__ import annotations

import copy
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import torch
import yaml

from _tiny_run import tiny_run
from idsplat_ns.errors import IDSplatError, one_line
from idsplat_ns.runs.checkpoints import (
    checkpoint_problem,
    keep_newest,
    latest_complete,
    list_checkpoints,
    load_latest,
    verify_written,
)

pytest.importorskip("nerfstudio")


# --- the checkpoint rules themselves ---------------------------------------------------------------

def _save(path: Path, step: int) -> Path:
    torch.save({"step": step, "pipeline": {"w": torch.arange(1000.0)}}, path)
    return path


def test_newest_loadable_checkpoint_and_the_two_kept(tmp_path: Path) -> None:
    for step in (3, 7, 12):
        _save(tmp_path / f"step-{step:09d}.ckpt", step)
    (tmp_path / "step-000000012.ckpt.tmp-1-abc").write_bytes(b"half")  # a save in progress: not a checkpoint
    assert [p.name for p in list_checkpoints(tmp_path)] == [f"step-{s:09d}.ckpt" for s in (12, 7, 3)]
    (tmp_path / "step-000000012.ckpt.tmp-1-abc").unlink()
    assert keep_newest(tmp_path) == [tmp_path / "step-000000003.ckpt"]
    newest = tmp_path / "step-000000012.ckpt"
    newest.write_bytes(newest.read_bytes()[:100])
    loaded = load_latest(tmp_path)
    assert loaded.step == 7 and loaded.skipped == [newest] and "unreadable checkpoint" in loaded.reasons[0]
    assert latest_complete(tmp_path).name == "step-000000007.ckpt"  # a cut archive has no zip index
    assert checkpoint_problem(tmp_path).startswith(f"{newest}: unreadable checkpoint")
    assert "the previous checkpoint step-000000007.ckpt loads" in checkpoint_problem(tmp_path)
    (tmp_path / "step-000000007.ckpt").write_bytes(b"")
    with pytest.raises(IDSplatError, match="no earlier checkpoint loads; train the run again"):
        load_latest(tmp_path)


def test_a_checkpoint_damaged_in_writing_is_caught_by_reading_it_back(tmp_path: Path) -> None:
    path = _save(tmp_path / "step-000000001.ckpt", 1)
    verify_written(path)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as archive:  # flip a byte inside the tensor data: the zip index stays intact
        info = max(archive.infolist(), key=lambda i: i.file_size)
    at = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra) + 100
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))
    assert zipfile.is_zipfile(path)
    with pytest.raises(IDSplatError, match="does not read back"):
        verify_written(path)


def test_stray_files_in_the_checkpoint_folder_are_named(tmp_path: Path) -> None:
    _save(tmp_path / "step-000000001.ckpt", 1)
    (tmp_path / "notes.txt").write_text("x")  # nerfstudio's loader would read its name as a step
    assert checkpoint_problem(tmp_path) == f"{tmp_path / 'notes.txt'}: not a step-*.ckpt checkpoint; move it out of {tmp_path}"
    assert checkpoint_problem(tmp_path / "none").endswith("none: no checkpoint folder; train the run first")


# --- every command on damaged runs ------------------------------------------------------------------

def _copy_run(config: Path, root: Path, edit=None) -> Path:
    """A copy of the run ``config`` under ``root`` (its config pointing at the copy)."""
    import method_configs.idsplat  # noqa: F401  (installs the excepthook translators)

    cfg = yaml.load(config.read_text(), Loader=yaml.Loader)
    dst = root / cfg.experiment_name / cfg.method_name / cfg.timestamp
    shutil.copytree(config.parent, dst)
    cfg.output_dir = root
    if edit is not None:
        cfg = edit(cfg) or cfg
    (dst / "config.yml").write_text(yaml.dump(cfg))
    return dst / "config.yml"


def _newest(config: Path) -> Path:
    return list_checkpoints(config.parent / "nerfstudio_models")[0]


def _other_method(cfg):
    from nerfstudio.configs.method_configs import all_methods

    other = copy.deepcopy(all_methods["splatfacto"])
    for name in ("output_dir", "experiment_name", "timestamp"):
        setattr(other, name, getattr(cfg, name))
    return other


def _moved_data(cfg):
    cfg.pipeline.datamanager.dataparser.data = Path(str(cfg.pipeline.datamanager.dataparser.data) + "-moved")


@pytest.fixture(scope="module")
def damaged(tiny_street: Path, tmp_path_factory) -> dict[str, Path]:
    source = tiny_run(tiny_street, tmp_path_factory)
    root = tmp_path_factory.mktemp("damaged_runs")
    runs = {name: _copy_run(source, root / name, edit) for name, edit in
            (("intact", None), ("no-checkpoint", None), ("truncated-0", None), ("truncated-100", None), ("newest-truncated", None),
             ("another-method", _other_method), ("data-moved", _moved_data))}
    _newest(runs["no-checkpoint"]).unlink()
    _newest(runs["truncated-0"]).write_bytes(b"")
    ckpt = _newest(runs["truncated-100"])
    ckpt.write_bytes(ckpt.read_bytes()[:100])
    ckpt = _newest(runs["newest-truncated"])
    shutil.copy(ckpt, ckpt.with_name("step-000000004.ckpt"))  # an earlier complete one beside it
    ckpt.write_bytes(ckpt.read_bytes()[:100])
    return runs


def _ns_eval(config: Path, out: Path) -> None:
    from nerfstudio.scripts.eval import ComputePSNR

    ComputePSNR(load_config=config, output_path=out / "eval.json").main()


def _ns_render(config: Path, out: Path) -> None:
    from nerfstudio.scripts.render import DatasetRender

    DatasetRender(load_config=config, output_path=out, rendered_output_names=["rgb"]).main()


def _idsplat(module: str, *args: str):
    def command(config: Path, out: Path) -> None:
        import importlib

        importlib.import_module(f"idsplat_ns.cli.{module}").main(["--load-config", str(config), *args, str(out)])
    return command


COMMANDS = {
    "ns-eval": _ns_eval,
    "ns-render": _ns_render,
    "idsplat-edit": _idsplat("edit", "--remove", "1", "--output-dir"),
    "idsplat-export": _idsplat("export", "--output-dir"),
    "idsplat-render-drive": _idsplat("render_drive", "--max-frames", "1", "--output"),
}
OURS = ("idsplat-edit", "idsplat-export", "idsplat-render-drive")
NEEDS_DATA = ("ns-eval", "ns-render", "idsplat-render-drive")


def _outcome(command, config: Path, out: Path, capsys) -> str | None:
    """None when the command succeeded, else the one line it ends in (the excepthook's or run_cli's)."""
    try:
        command(config, out)
    except SystemExit as end:
        assert end.code == 2, end.code
        err = capsys.readouterr().err.strip().splitlines()
        assert err and err[-1].startswith("error: "), err
        return err[-1][len("error: "):]
    except Exception as err:  # noqa: BLE001 - nerfstudio's own commands: what the excepthook would print
        line = one_line(type(err), err, err.__traceback__)
        assert line is not None, f"a traceback: {type(err).__name__}: {err}"
        return line
    return None


def _expected(case: str, name: str, config: Path) -> str | None:
    """What the line must hold (None: the command must succeed)."""
    models = config.parent / "nerfstudio_models"
    if case == "no-checkpoint":
        return f"{models}: no step-*.ckpt checkpoint"
    if case.startswith("truncated"):
        return f"{models / 'step-000000009.ckpt'}: unreadable checkpoint"
    if case == "newest-truncated":  # our loader falls back; nerfstudio's (render-drive's too) reads the newest name only
        return None if name in ("idsplat-edit", "idsplat-export") else "the previous checkpoint step-000000004.ckpt loads"
    if case == "another-method":
        return "a run of method 'splatfacto'"
    if case == "data-moved":
        return "-moved: no such file or folder" if name in NEEDS_DATA else None
    raise AssertionError(case)


CASES = ["no-checkpoint", "truncated-0", "truncated-100", "newest-truncated", "another-method", "data-moved"]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("name", list(COMMANDS))
def test_a_damaged_run_ends_in_one_line_and_leaves_nothing(damaged, case: str, name: str, tmp_path: Path, capsys) -> None:
    if case == "another-method" and name not in OURS:
        pytest.skip("ns-eval and ns-render evaluate another method's run as that method: nerfstudio's own business")
    config = damaged[case]
    out = tmp_path / "out" / "result"
    line = _outcome(COMMANDS[name], config, out, capsys)
    expected = _expected(case, name, config)
    if expected is None:
        assert line is None, line
        assert out.exists() or name == "idsplat-render-drive" and out.parent.exists()
        return
    assert line is not None and expected in line, line
    assert "\n" not in line
    assert not (tmp_path / "out").exists(), sorted((tmp_path / "out").rglob("*"))  # nothing the command made


# --- through the real entry points ------------------------------------------------------------------

def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONWARNINGS="ignore"))


@pytest.mark.slow
def test_ns_eval_and_ns_export_end_in_one_line_through_their_entry_points(damaged, tmp_path: Path) -> None:
    bin_dir = Path(sys.executable).parent
    config = damaged["truncated-100"]
    proc = _run([str(bin_dir / "ns-eval"), "--load-config", str(config), "--output-path", str(tmp_path / "e.json")], tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1].startswith(f"error: {_newest(config)}: unreadable checkpoint")

    good = damaged["intact"]
    proc = _run([str(bin_dir / "ns-export"), "gaussian-splat", "--load-config", str(good), "--output-dir",
                 str(tmp_path / "splat")], tmp_path)
    last = proc.stderr.strip().splitlines()[-1]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert last.startswith("error: ns-export does not export IDSplat runs") and f"idsplat-export --load-config {good}" in last
    assert not (tmp_path / "splat").exists()  # the folder ns-export made before failing is gone
