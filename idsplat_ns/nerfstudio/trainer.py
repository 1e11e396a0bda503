"""nerfstudio's Trainer with runs that survive a kill: atomic checkpoints and resume at the right step.

Three changes to nerfstudio's behaviour, each needed for ``kill -9`` then the same command again:

- A checkpoint is written under a temporary name, read back in full and renamed, and the previous
  one is kept beside it (:mod:`idsplat_ns.runs.checkpoints`): a kill during ``torch.save`` never
  leaves a truncated ``step-*.ckpt``, and a newest file damaged later still leaves one to resume
  from. A resume takes the newest checkpoint that loads, moves newer ones that do not to
  ``damaged_checkpoints/`` and says so in one line.
- A run folder that already holds checkpoints resumes from the latest one (``--load-config
  RUN/config.yml`` re-runs the same folder; so does a fixed ``--timestamp``), and
  ``--max-num-iterations`` stays the run's total: a run killed at step 700 of 1500 trains 800
  more, not 1500 more as nerfstudio would; a finished run trains nothing and ends cleanly.
- After loading, the optimizers are rebuilt on the model's current tensors: loading a checkpoint
  reallocates the Gaussians (MCMC grew them) and may rebuild the trajectories, and nerfstudio's
  optimizers, made before the load, would otherwise keep stepping the discarded tensors.
- Every random generator's state is saved with the checkpoint and restored
  (``random_state.py``), so the resumed run draws what the uninterrupted one would have drawn.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

import torch
from nerfstudio.engine.trainer import Trainer
from nerfstudio.utils.rich_utils import CONSOLE

from idsplat_ns.atomic import TMP_MARK, atomic_path
from idsplat_ns.runs.random_state import capture_random_state, restore_random_state
from idsplat_ns.runs.checkpoints import (
    LoadedCheckpoint,
    keep_newest,
    list_checkpoints,
    load_checkpoint,
    load_latest,
    set_aside,
    verify_written,
)


class IDSplatTrainer(Trainer):
    """nerfstudio's Trainer with atomic checkpoints and resume (see the module docstring)."""

    def _checkpoint_to_resume(self) -> Optional[LoadedCheckpoint]:
        """The checkpoint the options name, else the run's newest that loads (None: a new run)."""
        if self.config.load_checkpoint is not None:
            return load_checkpoint(Path(self.config.load_checkpoint))
        if self.config.load_dir is not None and self.config.load_step is not None:
            return load_checkpoint(Path(self.config.load_dir) / f"step-{self.config.load_step:09d}.ckpt")
        folder = Path(self.config.load_dir) if self.config.load_dir is not None else self.checkpoint_dir
        if self.config.load_dir is None and not list_checkpoints(folder):
            return None
        loaded = load_latest(folder)
        if loaded.skipped:
            moved = set_aside(loaded.skipped)
            CONSOLE.print(f"{'; '.join(loaded.reasons)}: resuming from {loaded.path.name} instead "
                          f"(moved to {moved[0].parent})", soft_wrap=True)  # one line, whatever the width
        return loaded

    def _load_checkpoint(self) -> None:
        if self.checkpoint_dir.is_dir():  # temporaries of a killed save (nerfstudio's loaders would misread them)
            for leftover in self.checkpoint_dir.glob(f"*{TMP_MARK}*"):
                leftover.unlink(missing_ok=True)
        loaded = self._checkpoint_to_resume()
        if loaded is None:
            CONSOLE.print("No checkpoint to resume from: training from step 0.")
            return
        path, state = loaded.path, loaded.state
        step = int(state["step"])
        self._start_step = step + 1
        self.step = step  # where the loop goes on (and what a finished run reports)
        self.pipeline.load_pipeline(state["pipeline"], step)
        self.optimizers = self.setup_optimizers()  # on the tensors the load allocated (module docstring)
        self.optimizers.load_optimizers(state["optimizers"])
        if "schedulers" in state and self.config.load_scheduler:
            self.optimizers.load_schedulers(state["schedulers"])
        self.grad_scaler.load_state_dict(state["scalers"])
        if "random" in state:  # checkpoints written before random states were kept resume without them
            restore_random_state(state["random"], self.pipeline.model, self.pipeline.datamanager, self.pipeline.device)
        total = self.config.max_num_iterations
        self.config.max_num_iterations = max(total - self._start_step, 0)
        CONSOLE.print(
            f"Resuming from {path} (step {step}): {self.config.max_num_iterations} of {total} steps left. "
            "Delete the run folder to start over.", soft_wrap=True
        )

    def train(self) -> None:
        """nerfstudio's training loop, except for a resumed run with no step left: that one only
        says so (the same command twice, e.g. ``make demo``; nerfstudio's end-of-training
        statistics would fail there with no step logged)."""
        if self._start_step > 0 and self.config.max_num_iterations == 0:
            CONSOLE.print(f"The run already holds its last step ({self.step}): nothing to train. "
                          "Delete the run folder to start over.")
            return
        super().train()

    def save_checkpoint(self, step: int) -> None:
        """nerfstudio's checkpoint, written under a temporary name and renamed."""
        self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
        path = self.checkpoint_dir / f"step-{step:09d}.ckpt"
        pipeline = self.pipeline.module if hasattr(self.pipeline, "module") else self.pipeline
        with atomic_path(path) as tmp:
            torch.save(
                {
                    "step": step,
                    "pipeline": pipeline.state_dict(),
                    "optimizers": {k: v.state_dict() for k, v in self.optimizers.optimizers.items()},
                    "schedulers": {k: v.state_dict() for k, v in self.optimizers.schedulers.items()},
                    "scalers": self.grad_scaler.state_dict(),
                    "random": capture_random_state(pipeline.model, pipeline.datamanager),
                },
                tmp,
            )
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())  # on disk before the rename makes it the checkpoint
            verify_written(tmp)  # a failure removes the temporary: the previous checkpoints stay
        if self.config.save_only_latest_checkpoint:
            keep_newest(self.checkpoint_dir)  # the newest and the one before it (module docstring)
