"""Adam with torch's fused update for every parameter group of the method.

nerfstudio gives each parameter group an optimizer of its own (about 15 for ``idsplat``); with
the per-tensor update each of them launches some ten operators a step, with the fused one a
single kernel (CUDA, and the CPU since torch 2.4). A training step on a GPU is bound by the host
launching operators (docs/reports/2026-11-28-gpu-ns-train.md), so this is time, not arithmetic.
"""

from __future__ import annotations

from dataclasses import dataclass

from nerfstudio.engine.optimizers import AdamOptimizerConfig


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """nerfstudio's Adam config with torch's fused implementation."""

    fused: bool = True
    """Update all of a group's tensors in one fused kernel (same maths as the per-tensor update)."""
