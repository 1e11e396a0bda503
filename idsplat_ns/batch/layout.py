"""Where a batch writes, and what a sequence's folder says about how far it got.

    OUTPUT_DIR/
      batch.log                      one line per state change (appended by every run)
      <method>_results.csv           the table: a row per finished sequence, the mean per protocol
      <method>_dpsnr.png             DPSNR per sequence
      <sequence>/<method>/run/       ns-train's run folder (config.yml, nerfstudio_models/step-*.ckpt)
      <sequence>/<method>/preprocess.log, train.log, eval.log    each step's output
      <sequence>/<method>/eval.json  ns-eval's metrics; its presence means the sequence is done
      <sequence>/<method>/status.json  the last state and, on failure, the step and its one-line error

ns-train's run folder is ``--output-dir OUTPUT_DIR --experiment-name <sequence> --timestamp run``,
so ``<sequence>/<method>/run`` is nerfstudio's own ``experiment/method/timestamp`` layout.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from idsplat_ns.atomic import atomic_path
from idsplat_ns.batch.commands import RUN_TIMESTAMP


@dataclass(frozen=True)
class SequencePaths:
    """The files of one sequence trained with one method."""

    output_dir: Path
    """The batch's --output-dir (ns-train's --output-dir)."""
    name: str
    """The sequence's folder name."""
    method: str
    """The ns-train method."""

    @property
    def folder(self) -> Path:
        return self.output_dir / self.name / self.method

    @property
    def run_dir(self) -> Path:
        return self.folder / RUN_TIMESTAMP

    @property
    def config(self) -> Path:
        return self.run_dir / "config.yml"

    @property
    def checkpoints(self) -> Path:
        return self.run_dir / "nerfstudio_models"

    @property
    def eval_json(self) -> Path:
        return self.folder / "eval.json"

    @property
    def status_json(self) -> Path:
        return self.folder / "status.json"

    def log(self, step: str) -> Path:
        return self.folder / f"{step}.log"


def write_status(paths: SequencePaths, status: dict) -> None:
    """Record the sequence's state (atomically: a kill never leaves half a JSON)."""
    paths.folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(paths.status_json) as tmp:
        tmp.write_text(json.dumps(status, indent=2))


def read_status(paths: SequencePaths) -> dict:
    """The recorded state, {} when there is none or it cannot be read."""
    try:
        return json.loads(paths.status_json.read_text())
    except (OSError, ValueError):
        return {}


def read_eval(paths: SequencePaths) -> Optional[dict]:
    """ns-eval's ``results`` of the sequence, None when there is no readable eval.json."""
    try:
        return dict(json.loads(paths.eval_json.read_text())["results"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
