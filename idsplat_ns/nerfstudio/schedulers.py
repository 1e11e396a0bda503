"""The learning-rate schedule of the paper's Table 10: optional warm-up, then exponential decay.

nerfstudio's own ``ExponentialDecayScheduler`` returns numpy scalars, which end up in the
optimisers' state inside checkpoints; torch >= 2.6 loads checkpoints with ``weights_only=True``
and refuses them, so ``ns-eval`` and ``ns-viewer`` could not load a model. This schedule computes
the same curve with plain Python floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Optional, Type

from nerfstudio.engine.schedulers import Scheduler, SchedulerConfig
from torch.optim import Optimizer, lr_scheduler


def exponential_decay_factor(
    step: int, lr_init: float, lr_final: float, warmup_steps: int, max_steps: int,
    lr_pre_warmup: float = 1e-8, ramp: str = "cosine",
) -> float:
    """Multiplier of ``lr_init`` at ``step``: ramp from ``lr_pre_warmup`` to ``lr_init`` over
    ``warmup_steps`` (cosine or linear), then log-linear decay to ``lr_final`` at ``max_steps``."""
    if step < warmup_steps:
        frac = min(max(step / warmup_steps, 0.0), 1.0)
        shape = math.sin(0.5 * math.pi * frac) if ramp == "cosine" else frac
        lr = lr_pre_warmup + (lr_init - lr_pre_warmup) * shape
    else:
        t = min(max((step - warmup_steps) / max(max_steps - warmup_steps, 1), 0.0), 1.0)
        lr = math.exp(math.log(lr_init) * (1 - t) + math.log(lr_final) * t)
    return lr / lr_init


@dataclass
class ExponentialDecaySchedulerConfig(SchedulerConfig):
    """Warm-up then exponential decay (the paper's Table 10 schedules)."""

    _target: Type = field(default_factory=lambda: ExponentialDecayScheduler)
    lr_pre_warmup: float = 1e-8
    """Learning rate at step 0 of the warm-up."""
    lr_final: Optional[float] = None
    """Learning rate at max_steps (None: constant after the warm-up)."""
    warmup_steps: int = 0
    """Steps of the warm-up ramp."""
    max_steps: int = 100000
    """Step at which the decay reaches lr_final."""
    ramp: Literal["linear", "cosine"] = "cosine"
    """Shape of the warm-up ramp."""


class ExponentialDecayScheduler(Scheduler):
    """LambdaLR over :func:`exponential_decay_factor` (Python floats only)."""

    config: ExponentialDecaySchedulerConfig

    def get_scheduler(self, optimizer: Optimizer, lr_init: float) -> lr_scheduler.LRScheduler:
        cfg = self.config
        lr_final = lr_init if cfg.lr_final is None else cfg.lr_final
        return lr_scheduler.LambdaLR(
            optimizer,
            lr_lambda=lambda step: exponential_decay_factor(
                step, lr_init, lr_final, cfg.warmup_steps, cfg.max_steps, cfg.lr_pre_warmup, cfg.ramp
            ),
        )
