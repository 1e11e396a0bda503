"""Training schedules that are not optimiser schedules: the resolution schedule."""

from __future__ import annotations

from typing import Sequence


def resolution_downscale(step: int, schedule: Sequence[int]) -> int:
    """Downscale factor at ``step`` for a schedule of step boundaries (paper: (3000, 6000)).

    Before the first boundary images are 1/2^len(schedule) of full size, halving the factor at
    each boundary: (3000, 6000) gives 4 for steps < 3000, 2 until 6000, then 1.
    """
    passed = sum(1 for b in schedule if step >= b)
    return 2 ** (len(schedule) - passed)
