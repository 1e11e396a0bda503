"""The batch's results table: a row per finished sequence and the mean per protocol, in the
layout of the paper's tables (camera: PSNR, SSIM, LPIPS, DPSNR; lidar: depth, intensity, drop
accuracy, Chamfer; tracking: MOTA, MOTP), as CSV, a printed table and a DPSNR bar plot."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from idsplat_ns.atomic import atomic_path
from idsplat_ns.eval.trajectory_plots import save_figure


@dataclass(frozen=True)
class Column:
    """One metric column of the table."""

    header: str
    """Printed header (with the paper's arrow: higher or lower is better)."""
    key: str
    """Key in ns-eval's ``results``."""
    digits: int
    """Decimals printed (the paper's)."""
    scale: float = 1.0
    """Factor applied to the stored value (ray-drop accuracy is printed in percent)."""


COLUMNS: tuple[Column, ...] = (
    Column("PSNR ↑", "psnr", 2),
    Column("SSIM ↑", "ssim", 3),
    Column("LPIPS ↓", "lpips", 3),
    Column("DPSNR ↑", "dpsnr", 2),
    Column("Depth ↓", "lidar_depth_median_sq_err", 3),
    Column("Intensity ↓", "lidar_intensity_rmse", 3),
    Column("Drop acc. ↑", "lidar_raydrop_acc", 1, 100.0),
    Column("CD ↓", "lidar_chamfer", 2),
    Column("MOTA@2m ↑", "mota@2m", 3),
    Column("MOTP@2m ↓", "motp@2m", 2),
)
"""All columns a table can have; a column that no sequence has (LPIPS without backbone weights,
lidar without lidar) is left out."""
NO_PROTOCOL = "-"


@dataclass(frozen=True)
class Row:
    """One line of the table."""

    sequence: str
    """Sequence name, or ``mean (N)`` for a protocol's mean of N sequences."""
    protocol: str
    """Protocol name, ``-`` for none."""
    values: dict[str, float]
    """Metric key -> value (already scaled), only the metrics present."""


def sequence_row(name: str, protocol: Optional[str], results: dict) -> Row:
    """A sequence's row from ns-eval's ``results``."""
    values = {}
    for col in COLUMNS:
        v = results.get(col.key)
        if isinstance(v, (int, float)) and math.isfinite(float(v)):
            values[col.key] = float(v) * col.scale
    return Row(name, protocol or NO_PROTOCOL, values)


def with_means(rows: Seq[Row]) -> list[Row]:
    """``rows`` grouped by protocol (in first-seen order), each group followed by its mean row.
    A metric's mean is over the sequences that have it."""
    out: list[Row] = []
    for protocol in dict.fromkeys(r.protocol for r in rows):
        group = [r for r in rows if r.protocol == protocol]
        out += group
        means = {}
        for col in COLUMNS:
            vals = [r.values[col.key] for r in group if col.key in r.values]
            if vals:
                means[col.key] = float(np.mean(vals))
        out.append(Row(f"mean ({len(group)})", protocol, means))
    return out


def present_columns(rows: Seq[Row]) -> list[Column]:
    """The columns that at least one row has."""
    return [c for c in COLUMNS if any(c.key in r.values for r in rows)]


def write_csv(rows: Seq[Row], path: Path) -> Path:
    """The table as CSV (full precision; empty cell: metric absent), written atomically."""
    cols = present_columns(rows)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["sequence", "protocol", *(c.key for c in cols)])
            for r in rows:
                w.writerow([r.sequence, r.protocol, *(repr(r.values[c.key]) if c.key in r.values else "" for c in cols)])
    return path


def print_table(rows: Seq[Row], title: str, print_fn: Callable[[object], None]) -> None:
    """The table with rich (mean rows in bold, a rule before each protocol's mean)."""
    from rich.table import Table

    cols = present_columns(rows)
    table = Table(title=title)
    table.add_column("sequence")
    table.add_column("protocol")
    for c in cols:
        table.add_column(c.header, justify="right")
    for r in rows:
        is_mean = r.sequence.startswith("mean (")
        cells = [f"{r.values[c.key]:.{c.digits}f}" if c.key in r.values else "-" for c in cols]
        table.add_row(r.sequence, r.protocol, *cells, style="bold" if is_mean else None, end_section=is_mean)
    print_fn(table)


def plot_dpsnr(rows: Seq[Row], path: Path, title: str) -> Optional[Path]:
    """Bar plot of DPSNR per sequence (coloured by protocol, the protocol's mean dashed); None
    when no sequence has a DPSNR (no moving vehicle in any held-out image)."""
    seqs = [r for r in rows if not r.sequence.startswith("mean (") and "dpsnr" in r.values]
    if not seqs:
        return None
    fig = Figure(figsize=(max(5.0, 0.35 * len(seqs) + 2.5), 3.6), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    protocols = list(dict.fromkeys(r.protocol for r in seqs))
    x = np.arange(len(seqs))
    colours = [f"C{protocols.index(r.protocol) % 10}" for r in seqs]
    ax.bar(x, [r.values["dpsnr"] for r in seqs], color=colours)
    for k, protocol in enumerate(protocols):
        idx = [i for i, r in enumerate(seqs) if r.protocol == protocol]
        mean = float(np.mean([seqs[i].values["dpsnr"] for i in idx]))
        ax.hlines(mean, idx[0] - 0.4, idx[-1] + 0.4, colors=f"C{k % 10}", linestyles="--",
                  label=f"{'no protocol' if protocol == NO_PROTOCOL else protocol}: mean {mean:.2f} dB")
    ax.set_xticks(x, [r.sequence for r in seqs], rotation=60 if len(seqs) > 6 else 0, ha="right" if len(seqs) > 6 else "center",
                  fontsize=7)
    ax.set_ylabel("DPSNR [dB]")
    ax.grid(True, axis="y", lw=0.3)
    ax.legend(loc="lower right", fontsize=7)
    ax.set_title(title)
    return save_figure(fig, path)
