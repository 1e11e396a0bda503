"""Top-view plots of predicted against ground-truth trajectories, one panel per sequence (the paper's
supplementary tracking figure). Uses matplotlib's Agg canvas directly: no pyplot global state."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from idsplat_ns.errors import IDSplatError
from idsplat_ns.atomic import atomic_path
from idsplat_ns.eval.tracking import Track, frame_sort_key


def tracks_by_id(frames: Track) -> dict[object, np.ndarray]:
    """Regroup ``{frame: {id: xyz}}`` into ``{id: positions [N, 2+]}`` in frame order."""
    out: dict[object, list[np.ndarray]] = {}
    for frame in sorted(frames, key=frame_sort_key):
        for obj, xyz in frames[frame].items():
            out.setdefault(obj, []).append(np.asarray(xyz, dtype=np.float64).reshape(-1))
    return {obj: np.stack(p) for obj, p in out.items()}


def _panel(ax, gt: Track, pred: Track, title: str | None) -> None:
    for n, (_, xy) in enumerate(tracks_by_id(gt).items()):
        ax.plot(xy[:, 0], xy[:, 1], "-", color="black", lw=2.0, alpha=0.5, label="ground truth" if n == 0 else None)
    cmap = [f"C{k}" for k in range(10)]
    for n, (_, xy) in enumerate(tracks_by_id(pred).items()):
        ax.plot(xy[:, 0], xy[:, 1], "-", color=cmap[n % 10], lw=1.2, label="predicted" if n == 0 else None)
        ax.plot(xy[:1, 0], xy[:1, 1], "o", color=cmap[n % 10], ms=3)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3)
    if title:
        ax.set_title(title)
    ax.legend(loc="best", fontsize=7)


def plot_trajectories(
    sequences: Sequence[tuple[str, Track, Track]],
    path: str | os.PathLike,
    panel_size: float = 4.0,
) -> Path:
    """Write a PNG with one top-view panel per ``(name, gt, pred)`` sequence; returns the path.

    ``gt`` and ``pred`` map each frame to ``{object_id: xyz}`` (as for
    :func:`idsplat_ns.eval.tracking.clear_mot`). Ground truth is drawn in grey, each predicted
    track in its own colour with a dot at its start. The file is written to a temporary name and
    renamed, so a failed run leaves no half-written PNG.
    """
    if not sequences:
        raise IDSplatError(f"plot_trajectories: no sequence to plot into {path}")
    path = Path(path)
    cols = min(len(sequences), 5)
    rows = (len(sequences) + cols - 1) // cols
    fig = Figure(figsize=(panel_size * cols, panel_size * rows), dpi=100)
    FigureCanvasAgg(fig)
    for k, (name, gt, pred) in enumerate(sequences):
        _panel(fig.add_subplot(rows, cols, k + 1), gt, pred, name)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path
