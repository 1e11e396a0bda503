"""Run time and accuracy of the CT smoother on synthetic turning trajectories (noise 0.5 m,
10% outliers at 5 m, 20% of steps missing). Prints a table. Usage:
    .venv/bin/python bench/smoothing_runtime.py
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_smoothing import corrupt, ct_trajectory, position_rmse  # noqa: E402  (the tests' generator)

from idsplat_ns.instances.smoothing import smooth_trajectory  # noqa: E402


def main() -> None:
    print("| steps | run time [s] (median of 3) | raw RMSE [m] | smoothed RMSE [m] | outliers flagged / true | false flags |")
    print("|---|---|---|---|---|---|")
    for steps in (50, 100, 200, 400):
        times, truth, _ = ct_trajectory(steps=steps, accel=0.3, curvature=lambda t: 0.03 * math.sin(t / 4.0))
        meas, valid, outlier = corrupt(truth, np.random.default_rng(steps))
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            result = smooth_trajectory(times, meas, valid)
            runs.append(time.perf_counter() - t0)
        flagged = valid & ~result.inliers
        true_out = valid & outlier
        print(
            f"| {steps} | {np.median(runs):.2f} | {position_rmse(meas[valid], truth[valid]):.2f} "
            f"| {position_rmse(result.poses, truth):.2f} | {(flagged & true_out).sum()} / {true_out.sum()} "
            f"| {(flagged & ~true_out).sum()} |"
        )


if __name__ == "__main__":
    main()
