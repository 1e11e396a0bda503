"""The house's layers as a contract (``[tool.importlinter]`` in pyproject.toml): errors, atomic,
_compat < data, render < instances < model < eval < runs < the nerfstudio adapter < command
lines, batch < method_configs, and no import cycle in any package. import-linter reads every
import statement, those inside functions and under TYPE_CHECKING included."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_imports_keep_the_layers_and_make_no_cycle() -> None:
    lint = Path(sys.executable).with_name("lint-imports")
    done = subprocess.run([str(lint), "--config", str(REPO / "pyproject.toml"), "--no-cache"], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert "2 kept, 0 broken" in done.stdout, done.stdout[-2000:]


def test_the_contract_catches_an_upward_import(tmp_path: Path) -> None:
    """The check can fail: a copy of the package where data imports the model breaks it."""
    import shutil

    for name in ("idsplat_ns", "method_configs"):
        shutil.copytree(REPO / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "pyproject.toml", tmp_path / "pyproject.toml")
    with open(tmp_path / "idsplat_ns" / "data" / "split.py", "a") as fh:
        fh.write("\n\ndef _upward():\n    from idsplat_ns.model import gaussians  # noqa: F401\n")
    lint = Path(sys.executable).with_name("lint-imports")
    done = subprocess.run([str(lint), "--config", str(tmp_path / "pyproject.toml"), "--no-cache"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300, env={"PYTHONPATH": str(tmp_path), "PATH": ""})
    assert done.returncode != 0 and "idsplat_ns.data.split -> idsplat_ns.model.gaussians" in done.stdout, done.stdout[-3000:]
