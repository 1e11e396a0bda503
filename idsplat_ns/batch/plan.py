"""What is left to do for each sequence, from what its folder holds (the batch's resumability).

- ``eval.json`` readable: done, skipped.
- the run's newest checkpoint is the last step: training is complete, only evaluation is left.
- a checkpoint before the last step: training resumes from it (preprocessing is not repeated: the
  training that wrote the checkpoint had its instances). The resume is the same ns-train command:
  the project's trainer continues a run folder from its latest checkpoint.
- otherwise: preprocessing (unless ``instance-mode static``), training, evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from idsplat_ns.batch.commands import UserOptions, eval_command, preprocess_command, train_command
from idsplat_ns.batch.layout import SequencePaths, read_eval
from idsplat_ns.runs.checkpoints import checkpoint_step, latest_complete
from idsplat_ns.batch.sequences import Sequence

STEPS = ("preprocess", "train", "eval")
EVAL_PARTIAL = "eval.partial.json"
"""ns-eval writes here; renamed to eval.json on success, so eval.json always is a complete run's."""


@dataclass(frozen=True)
class Step:
    """One step of one sequence: its kind, its command and a line saying what it does."""

    kind: str
    """``preprocess``, ``train`` or ``eval``."""
    argv: tuple[str, ...]
    """The command (program name first)."""
    note: str
    """Shown in the state line (``resume from step 9``), may be empty."""


@dataclass(frozen=True)
class SequencePlan:
    """A sequence with the steps it still needs (none: already evaluated)."""

    sequence: Sequence
    """The sequence."""
    paths: SequencePaths
    """Its files."""
    steps: tuple[Step, ...]
    """Steps left, in order."""


def plan_sequence(seq: Sequence, method: str, user: UserOptions, output_dir: Path,
                  total_steps: Callable[[], int]) -> SequencePlan:
    """The steps left for ``seq``; ``total_steps`` (the length of a complete training) is only
    asked for when a checkpoint exists, since finding a method's default imports nerfstudio."""
    paths = SequencePaths(output_dir, seq.name, method)
    evaluate = Step("eval", tuple(eval_command(paths.config, paths.folder / EVAL_PARTIAL)), "")
    if read_eval(paths) is not None:
        return SequencePlan(seq, paths, ())
    checkpoint = latest_complete(paths.checkpoints)
    if checkpoint is not None and paths.config.is_file():
        last = checkpoint_step(checkpoint)
        left = total_steps() - 1 - last  # nerfstudio's last checkpoint of N steps is step N-1
        if left <= 0:
            return SequencePlan(seq, paths, (evaluate,))
        train = train_command(seq, method, user, output_dir)
        return SequencePlan(seq, paths, (Step("train", tuple(train), f"resume from step {last}, {left} steps left"), evaluate))
    steps = []
    pre = preprocess_command(seq, user)
    if pre is not None:
        steps.append(Step("preprocess", tuple(pre), ""))
    steps.append(Step("train", tuple(train_command(seq, method, user, output_dir)), ""))
    steps.append(evaluate)
    return SequencePlan(seq, paths, tuple(steps))


def finish_eval(paths: SequencePaths) -> Optional[dict]:
    """After ns-eval succeeded: move its output to eval.json; returns the results (None if unreadable)."""
    partial = paths.folder / EVAL_PARTIAL
    if partial.is_file():
        partial.replace(paths.eval_json)
    return read_eval(paths)
