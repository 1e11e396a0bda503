"""A run's checkpoints: how a new one is kept, and which one every reader loads.

nerfstudio names them ``step-<9 digits>.ckpt`` in a run's ``nerfstudio_models/``. Writing (the
trainer): under a temporary name, read back in full (a checkpoint is a zip archive; every member's
CRC is checked), renamed, and only then are all but the newest :data:`KEPT` removed, so a newest
file damaged later (a copy cut short, a full disk) still leaves the previous one. Reading (training
resume, ``idsplat-edit``/``-export``, the viewer, the batch): the newest checkpoint that loads, each
newer one that does not named in one line. nerfstudio's own loader (``ns-eval``, ``ns-render``,
``ns-viewer``) takes the newest name whatever it holds: :func:`checkpoint_problem` is the one line
that its failure is translated into (:mod:`idsplat_ns.cli.command_failures`).
"""

from __future__ import annotations

import re
import shutil
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import torch

from idsplat_ns.errors import IDSplatError

CHECKPOINT_GLOB = "step-*.ckpt"
KEPT = 2
"""Checkpoints a run keeps: the newest and the one before it."""
DAMAGED_DIR = "damaged_checkpoints"
"""Beside ``nerfstudio_models/``: where a resume moves checkpoints that do not load (kept, not deleted)."""
_NAME = re.compile(r"^step-(\d+)\.ckpt$")


def checkpoint_step(path: Path) -> int:
    """The step in a checkpoint's name ``step-000001234.ckpt``."""
    match = _NAME.match(Path(path).name)
    if match is None:
        raise ValueError(f"{path}: not a step-*.ckpt name")
    return int(match.group(1))


def list_checkpoints(folder: Path) -> list[Path]:
    """The checkpoints in ``folder``, newest step first (temporaries of a save in progress left out)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted((p for p in folder.iterdir() if _NAME.match(p.name)), key=checkpoint_step, reverse=True)


def latest_complete(folder: Path) -> Optional[Path]:
    """The newest checkpoint whose zip index is intact (cheap: reads the archive's end record), or None."""
    return next((p for p in list_checkpoints(folder) if zipfile.is_zipfile(p)), None)


def verify_written(path: Path) -> None:
    """Raise a one-line :class:`IDSplatError` unless every member of the archive at ``path`` reads back."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (OSError, zipfile.BadZipFile) as err:
        raise IDSplatError(f"{path}: the checkpoint just written does not read back ({type(err).__name__}); "
                           "the previous checkpoint is kept: check the disk (space, errors)") from None
    if bad is not None:
        raise IDSplatError(f"{path}: the checkpoint just written does not read back ({bad} is damaged); "
                           "the previous checkpoint is kept: check the disk (space, errors)")


def keep_newest(folder: Path, keep: int = KEPT) -> list[Path]:
    """Delete all but the newest ``keep`` checkpoints; returns those deleted."""
    old = list_checkpoints(folder)[keep:]
    for path in old:
        path.unlink(missing_ok=True)
    return old


@dataclass
class LoadedCheckpoint:
    """A checkpoint read into memory (CPU tensors)."""

    path: Path
    """The file loaded."""
    state: dict
    """Its content: ``step``, ``pipeline`` and, from training, the optimiser state."""
    why_skipped: dict[Path, str] = field(default_factory=dict)
    """Newer checkpoints that did not load, newest first, each with why."""

    @property
    def step(self) -> int:
        return int(self.state["step"])

    @property
    def skipped(self) -> list[Path]:
        """Newer checkpoints that did not load."""
        return list(self.why_skipped)

    @property
    def reasons(self) -> list[str]:
        """One line per skipped checkpoint: its path and why."""
        return [f"{path}: {why}" for path, why in self.why_skipped.items()]


def _read(path: Path) -> tuple[Optional[dict], str]:
    """(state, "") or (None, why ``path`` is not a loadable checkpoint)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # noqa: BLE001 - whatever a damaged archive makes the unpickler raise, the file is unreadable
        return None, f"unreadable checkpoint ({type(err).__name__})"
    if not isinstance(state, dict) or "step" not in state or "pipeline" not in state:
        return None, "not a nerfstudio checkpoint (no step and pipeline)"
    return state, ""


def load_checkpoint(path: Path) -> LoadedCheckpoint:
    """Exactly the checkpoint at ``path`` (one line naming it when it does not load)."""
    path = Path(path)
    if not path.is_file():
        raise IDSplatError(f"{path}: no such checkpoint file")
    state, why = _read(path)
    if state is None:
        raise IDSplatError(f"{path}: {why}")
    return LoadedCheckpoint(path, state)


def load_latest(folder: Path) -> LoadedCheckpoint:
    """The newest checkpoint in ``folder`` that loads; newer ones that do not are listed in ``skipped``.

    Raises a one-line :class:`IDSplatError` when the folder holds none, or none that loads."""
    problem = folder_problem(Path(folder))
    if problem is not None:
        raise IDSplatError(problem)
    why_skipped: dict[Path, str] = {}
    for path in list_checkpoints(folder):
        state, why = _read(path)
        if state is not None:
            return LoadedCheckpoint(path, state, why_skipped)
        why_skipped[path] = why
    newest, why = next(iter(why_skipped.items()))
    raise IDSplatError(_none_loads(f"{newest}: {why}"))


def _none_loads(newest: str) -> str:
    return f"{newest}, and no earlier checkpoint loads; train the run again (delete its nerfstudio_models/ folder)"


def set_aside(paths: list[Path]) -> list[Path]:
    """Move checkpoints that do not load to ``damaged_checkpoints/`` beside their folder (nerfstudio's
    loader reads every name in ``nerfstudio_models/``, so they cannot stay there renamed)."""
    moved = []
    for path in paths:
        target = path.parent.parent / DAMAGED_DIR / path.name
        target.parent.mkdir(exist_ok=True)
        shutil.move(str(path), str(target))
        moved.append(target)
    return moved


def folder_problem(folder: Path, strays: bool = False) -> Optional[str]:
    """Why ``folder`` holds no checkpoint to load, found without loading one: it is missing, holds
    no ``step-*.ckpt``, or (``strays``) holds another file, which nerfstudio's loader would read as a
    step. None when there are checkpoints to try."""
    folder = Path(folder)
    if not folder.is_dir():
        return f"{folder}: no checkpoint folder; train the run first"
    names = sorted(p.name for p in folder.iterdir() if not _NAME.match(p.name)) if strays else []
    if names:
        return f"{folder / names[0]}: not a step-*.ckpt checkpoint; move it out of {folder}"
    if not list_checkpoints(folder):
        return f"{folder}: no step-*.ckpt checkpoint; train the run first"
    return None


def checkpoint_problem(folder: Path) -> Optional[str]:
    """Why nerfstudio's loader (newest name, every name in the folder parsed as a step) cannot load
    ``folder``, as one line; None when it should (the failure is then not the checkpoint's)."""
    folder = Path(folder)
    problem = folder_problem(folder, strays=True)
    if problem is not None:
        return problem
    found = list_checkpoints(folder)
    state, why = _read(found[0])
    if state is not None:
        return None
    earlier = next((p for p in found[1:] if _read(p)[0] is not None), None)
    if earlier is None:
        return _none_loads(f"{found[0]}: {why}")
    return (f"{found[0]}: {why}; the previous checkpoint {earlier.name} loads: move the damaged one out of "
            f"{folder.name}/ (a resumed ns-train moves it to {DAMAGED_DIR}/ by itself)")
