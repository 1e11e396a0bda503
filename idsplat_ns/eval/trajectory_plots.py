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
from idsplat_ns.model.instance_palette import instance_rgb



def save_figure(fig: Figure, path: Path) -> Path:
    """Lay out ``fig`` and write it to ``path`` as PNG, atomically (the folder is made)."""
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path

def tracks_by_id(frames: Track) -> dict[object, np.ndarray]:
    """Regroup ``{frame: {id: xyz}}`` into ``{id: positions [N, 2+]}`` in frame order."""
    out: dict[object, list[np.ndarray]] = {}
    for frame in sorted(frames, key=frame_sort_key):
        for obj, xyz in frames[frame].items():
            out.setdefault(obj, []).append(np.asarray(xyz, dtype=np.float64).reshape(-1))
    return {obj: np.stack(p) for obj, p in out.items()}


def _colour(obj: object, n: int):
    """An instance ID's colour of the instance renders and the viewer (model/instance_palette.py);
    other keys (a test's names) take matplotlib's cycle by order."""
    if isinstance(obj, (int, np.integer)) and not isinstance(obj, bool) and obj > 0:
        return instance_rgb(int(obj))
    return f"C{n % 10}"


def _panel(ax, gt: Track, pred: Track, title: str | None, ego: np.ndarray | None = None, label_ids: bool = False) -> None:
    """One top view; ``ego`` [F, 2+] is drawn dashed with an arrow at its end; ``label_ids`` writes
    each predicted track's ID at its start (the IDs idsplat-edit takes)."""
    if ego is not None and len(ego):
        ax.plot(ego[:, 0], ego[:, 1], "--", color="0.35", lw=1.2, label="ego path")
        if len(ego) > 1:
            ax.annotate("", xy=ego[-1, :2], xytext=ego[-2, :2], arrowprops={"arrowstyle": "->", "color": "0.35"})
    for n, (_, xy) in enumerate(tracks_by_id(gt).items()):
        ax.plot(xy[:, 0], xy[:, 1], "-", color="black", lw=2.0, alpha=0.5, label="ground truth" if n == 0 else None)
    for n, (obj, xy) in enumerate(tracks_by_id(pred).items()):
        colour = _colour(obj, n)
        ax.plot(xy[:, 0], xy[:, 1], "-", color=colour, lw=1.2, label="predicted" if n == 0 else None)
        ax.plot(xy[:1, 0], xy[:1, 1], "o", color=colour, ms=3)
        if label_ids:
            ax.annotate(str(obj), xy[0, :2], xytext=(3, 3), textcoords="offset points", color=colour, fontsize=8,
                        fontweight="bold")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3)
    if title:
        ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:  # an empty panel has nothing to explain
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
    return save_figure(fig, path)


def plot_scene_top_view(
    gt: Track,
    pred: Track,
    ego: np.ndarray,  # [F, 2+] ego positions (world, metres) in time order
    path: str | os.PathLike,
    title: str = "",
    size: float = 7.0,
) -> Path:
    """Write one top view of a sequence: annotated tracks (grey), learned instance trajectories
    (coloured, labelled with their instance IDs) and the ego path (dashed). Atomic like
    :func:`plot_trajectories`."""
    path = Path(path)
    fig = Figure(figsize=(size, size), dpi=110)
    FigureCanvasAgg(fig)
    _panel(fig.add_subplot(1, 1, 1), gt, pred, title or None, ego=np.asarray(ego, dtype=np.float64), label_ids=True)
    return save_figure(fig, path)


def position_errors(gt: Track, pred: Track) -> dict[object, tuple[np.ndarray, np.ndarray]]:
    """Per predicted ID: (frames [K], distance to its ground-truth track [K] metres). Each
    prediction is paired with the ground-truth track nearest to it at the first frame where any
    exists (a fixed pairing, so that an identity switch shows as a jump rather than being hidden)."""
    frames = sorted(set(gt) | set(pred), key=frame_sort_key)
    owner: dict[object, object] = {}
    out: dict[object, tuple[list, list]] = {}
    for frame in frames:
        truth = gt.get(frame, {})
        for obj, xyz in pred.get(frame, {}).items():
            xyz = np.asarray(xyz, dtype=np.float64).reshape(-1)[:3]
            if obj not in owner and truth:
                owner[obj] = min(truth, key=lambda k: float(np.linalg.norm(np.asarray(truth[k])[:3] - xyz)))
            if obj in owner and owner[obj] in truth:
                out.setdefault(obj, ([], []))
                out[obj][0].append(frame)
                out[obj][1].append(float(np.linalg.norm(np.asarray(truth[owner[obj]], dtype=np.float64)[:3] - xyz)))
    return {obj: (np.asarray(f), np.asarray(e)) for obj, (f, e) in out.items()}


def plot_position_errors(gt: Track, pred: Track, path: str | os.PathLike, title: str = "") -> Path:
    """Write the per-instance position error over frames (see :func:`position_errors`); an empty
    panel with a note when nothing can be paired (no annotations)."""
    path = Path(path)
    fig = Figure(figsize=(7.0, 3.8), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    errors = position_errors(gt, pred)
    for n, (obj, (frames, err)) in enumerate(sorted(errors.items(), key=lambda kv: frame_sort_key(kv[0]))):
        ax.plot(frames, err, "o-", ms=3, lw=1.0, color=_colour(obj, n), label=f"ID {obj}")
    if not errors:
        ax.text(0.5, 0.5, "no annotated track to compare with", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("frame")
    ax.set_ylabel("position error [m]")
    ax.grid(True, lw=0.3)
    if errors:
        ax.legend(loc="best", fontsize=7, ncol=max(1, len(errors) // 8))
    if title:
        ax.set_title(title)
    return save_figure(fig, path)
