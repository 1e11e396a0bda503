"""Metric plots of an evaluation: PSNR of every held-out image and DPSNR where the image shows a
moving road user, so that a bad mean can be traced to the images behind it; the lidar range error
by distance, so that a depth error can be placed near or far. Uses matplotlib's Agg canvas
directly (no pyplot global state); written atomically."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from idsplat_ns.eval.lidar_metrics import range_error_by_distance
from idsplat_ns.eval.trajectory_plots import save_figure
from idsplat_ns.errors import IDSplatError


def plot_per_image(per_image: Sequence[dict], path: str | os.PathLike, title: str = "") -> Path:
    """Write PSNR (and DPSNR of each class where present) per image index from ``[{metric: value}]``."""
    if not per_image:
        raise IDSplatError(f"plot_per_image: no image metrics to plot into {path}")
    path = Path(path)
    idx = np.arange(len(per_image))
    fig = Figure(figsize=(max(6.0, 0.12 * len(per_image) + 3), 3.6), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    psnr = np.array([m.get("psnr", np.nan) for m in per_image], dtype=np.float64)
    ax.plot(idx, psnr, "o-", ms=3, lw=1.0, color="C0", label=f"PSNR (mean {np.nanmean(psnr):.2f})")
    for key, marker, color, name in (("dpsnr", "s", "C3", "moving vehicles"), ("dpsnr_pedestrian", "^", "C2", "pedestrians"),
                                     ("dpsnr_cyclist", "v", "C4", "cyclists")):
        dpsnr = np.array([m.get(key, np.nan) for m in per_image], dtype=np.float64)
        if np.isfinite(dpsnr).any():
            ax.plot(idx, dpsnr, marker, ms=4, color=color, label=f"DPSNR, {name} (mean {np.nanmean(dpsnr):.2f})")
    ax.set_xlabel("held-out image")
    ax.set_ylabel("dB")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=7)
    if title:
        ax.set_title(title)
    return save_figure(fig, path)


def plot_lidar_error_by_range(
    gt_range: np.ndarray,  # [K] measured range, metres
    abs_error: np.ndarray,  # [K] absolute range error, metres
    path: str | os.PathLike,
    title: str = "",
    bin_width: float = 10.0,
) -> Path:
    """Write the median absolute range error (with its interquartile band) per range bin, and the
    number of rays per bin underneath, for the held-out lidar rays returned in data and model."""
    path = Path(path)
    if np.size(gt_range) == 0:
        raise IDSplatError(f"plot_lidar_error_by_range: no returned lidar rays to plot into {path}")
    bins = range_error_by_distance(gt_range, abs_error, bin_width)
    centres = 0.5 * (bins["edges"][:-1] + bins["edges"][1:])
    fig = Figure(figsize=(6.4, 4.4), dpi=110)
    FigureCanvasAgg(fig)
    ax, ax_n = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    floor = 1e-4  # a log axis cannot show an exact 0 (a perfect bin): drawn at 0.1 mm
    ax.fill_between(centres, np.maximum(bins["p25"], floor), np.maximum(bins["p75"], floor), color="C0", alpha=0.25,
                    lw=0, label="25-75 %")
    ax.plot(centres, np.maximum(bins["median"], floor), "o-", ms=3, color="C0", label="median")
    ax.set_yscale("log")
    ax.set_ylabel("|range error| (m)")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(loc="upper left", fontsize=7)
    ax_n.bar(centres, bins["count"], width=0.8 * bin_width, color="0.6")
    ax_n.set_ylabel("rays")
    ax_n.set_xlabel("measured range (m)")
    if title:
        ax.set_title(title)
    return save_figure(fig, path)

