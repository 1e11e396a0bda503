"""Per-image metric plot of an evaluation: PSNR of every held-out image and DPSNR where the image
shows a moving vehicle, so that a bad mean can be traced to the images behind it. Uses
matplotlib's Agg canvas directly (no pyplot global state); written atomically."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

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
