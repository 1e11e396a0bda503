"""The per-object diagnosis as a picture: one row per annotated moving road user, a mark per frame
it counts in (green tracked, red lost), shaded where it is within 10 m of the ego, so that a user
sees at once which object failed, when, and how close it was. Matplotlib's Agg canvas, no pyplot
state; written atomically."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from idsplat_ns.errors import IDSplatError
from idsplat_ns.eval.object_diagnosis import NEAR_EGO, ObjectRecord
from idsplat_ns.eval.trajectory_plots import save_figure


def plot_object_timeline(records: Sequence[ObjectRecord], path: str | os.PathLike, title: str = "") -> Path:
    """Write the timeline of ``records`` (their order, top to bottom) to ``path``."""
    if not records:
        raise IDSplatError(f"plot_object_timeline: no annotated moving object to plot into {path}")
    path = Path(path)
    fig = Figure(figsize=(11.0, 0.9 + 0.32 * len(records)), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    labels = []
    for row, rec in enumerate(records):
        y = len(records) - 1 - row
        frames = np.asarray(rec.frames)
        near = np.asarray(rec.distance_to_ego) < NEAR_EGO
        tracked = np.asarray(rec.tracked, dtype=bool)
        for f in frames[near]:
            ax.axvspan(f - 0.5, f + 0.5, ymin=(y + 0.1) / len(records), ymax=(y + 0.9) / len(records),
                       color="0.85", lw=0)  # fmt: skip
        ax.scatter(frames[tracked], np.full(tracked.sum(), y), marker="s", s=14, color="tab:green")
        ax.scatter(frames[~tracked], np.full((~tracked).sum(), y), marker="s", s=14, color="tab:red")
        dpsnr = "" if rec.dpsnr is None else f", DPSNR {rec.dpsnr:.1f}"
        labels.append(f"{rec.name} ({rec.label}{dpsnr}, {min(rec.distance_to_ego):.0f} m)")
    ax.set_yticks(range(len(records)), labels[::-1], fontsize=7)
    ax.set_ylim(-0.5, len(records) - 0.5)
    ax.set_xlabel(f"frame (green tracked, red lost at 2 m; grey: within {NEAR_EGO:g} m of the ego)")
    ax.set_title(title, fontsize=9)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)
