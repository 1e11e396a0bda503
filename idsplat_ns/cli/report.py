"""Print an ``ns-eval`` result as tables (image and lidar metrics; tracking per class with its
counts; the objects lost, frame by frame), the notes on metrics the data could not support, and
where the renders and checkpoint are."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from rich.console import Console
from rich.table import Table

from idsplat_ns.errors import IDSplatError, run_cli

ROWS = (
    ("psnr", "PSNR (dB)"),
    ("ssim", "SSIM"),
    ("dpsnr", "DPSNR (dB, moving vehicles)"),
    ("dpsnr_pedestrian", "DPSNR (dB, pedestrians)"),
    ("dpsnr_cyclist", "DPSNR (dB, cyclists)"),
    ("lpips", "LPIPS"),
    ("mota@2m", "tracking MOTA @ 2 m (observed vehicles)"),
    ("motp@2m", "tracking MOTP @ 2 m (m)"),
    ("all_mota@2m", "tracking MOTA @ 2 m (all annotated vehicles, seen or not)"),
    ("lidar_depth_median_sq_err", "lidar depth median squared error (m^2)"),
    ("lidar_intensity_rmse", "lidar intensity RMSE"),
    ("lidar_raydrop_acc", "lidar ray-drop accuracy"),
    ("lidar_chamfer", "lidar Chamfer distance (m)"),
    ("render_mpix_per_s", "render speed (MP/s)"),
)

TRACKING_ROWS = (("", "vehicles (headline)"), ("pedestrian_", "pedestrians"), ("cyclist_", "cyclists"),
                 ("road_users_", "all moving road users"), ("all_", "vehicles, seen or not"))
"""Key prefix and name of each tracking evaluation (eval/trajectory_eval.py: tracking_metrics)."""
TRACKING_COLUMNS = (("objects", "objects"), ("matches", "matches"), ("id_switches", "switches"),
                    ("false_positives", "FP"), ("misses", "FN"), ("mota", "MOTA"), ("motp", "MOTP (m)"))


def tracking_table(results: dict, threshold: str = "2m") -> Table | None:
    """Per-class CLEAR-MOT at one threshold, one row per evaluation present in ``results``."""
    rows = [(prefix, name) for prefix, name in TRACKING_ROWS if f"{prefix}mota@{threshold}" in results]
    if not rows:
        return None
    table = Table(title=f"Tracking @ {threshold[:-1]} m (CLEAR-MOT; other classes' regions are don't care)")
    table.add_column("class")
    for _, name in TRACKING_COLUMNS:
        table.add_column(name, justify="right")
    for prefix, name in rows:
        cells = []
        for key, _ in TRACKING_COLUMNS:
            value = results.get(f"{prefix}{key}@{threshold}")
            cells.append("" if value is None else f"{value:.0f}" if key not in ("mota", "motp") else f"{value:.3f}")
        table.add_row(name, *cells)
    return table


OBJECT_COLUMNS = (("name", "object"), ("label", "class"), ("frames", "frames"), ("frames_lost", "lost"),
                  ("frames_lost_near", "lost < 10 m"), ("longest_lost", "longest gap"), ("fragments", "tracks"),
                  ("min_distance_to_ego", "closest (m)"), ("dpsnr", "DPSNR"))  # fmt: skip


def objects_table(results: dict, rows: int = 12) -> Table | None:
    """The annotated moving objects with the most lost frames (ns-eval's ``objects``), worst first;
    None when every object was tracked in every frame it counts."""
    objects = [o for o in results.get("objects", []) if o["frames_lost"] or o["fragments"] > 1]
    if not objects:
        return None
    objects = sorted(objects, key=lambda o: (-o["frames_lost"], -o["fragments"]))[:rows]
    table = Table(title="Objects lost at 2 m (frames the observed protocol counts; the full list is ns-eval's "
                        "JSON 'objects', the picture plots/objects_timeline.png)")  # fmt: skip
    for _, name in OBJECT_COLUMNS:
        table.add_column(name, justify="left" if name in ("object", "class") else "right")
    for o in objects:
        table.add_row(*("" if o.get(k) is None else str(o[k]) for k, _ in OBJECT_COLUMNS))
    return table


def notes(results: dict) -> list[str]:
    """The one-line notes of metrics left out (``<metric>_note`` keys), in key order."""
    return [str(results[k]) for k in sorted(results) if k.endswith("_note")]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="idsplat-report", description=__doc__)
    parser.add_argument("eval_json", type=Path, help="the JSON that ns-eval --output-path wrote")
    parser.add_argument("--renders", type=Path, default=None, help="ns-eval's --render-output-path, to print where it is")
    parser.add_argument("--checkpoint-dir", type=Path, default=None, help="the run's nerfstudio_models/, to print its newest checkpoint")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)

    def run() -> None:
        if not args.eval_json.is_file():
            raise IDSplatError(f"{args.eval_json}: no evaluation result; run ns-eval first")
        data = json.loads(args.eval_json.read_text())
        results = data["results"]
        table = Table(title=f"Held-out evaluation: {data.get('experiment_name', '')} ({results.get('num_images', '?')} images)")
        table.add_column("metric")
        table.add_column("mean", justify="right")
        table.add_column("std", justify="right")
        for key, name in ROWS:
            if key in results:
                n = results.get(f"{key}_num_images")
                label = name + (f" [{n} images]" if n is not None else "")
                std = results.get(key + "_std")
                table.add_row(label, f"{results[key]:.4f}", "" if std is None else f"{std:.4f}")
        console = Console()
        if not console.is_terminal and "COLUMNS" not in os.environ:
            console = Console(width=140)  # piped or captured (make demo's log): rich would wrap at 80 columns
        console.print(table)
        tracking = tracking_table(results)
        if tracking is not None:
            console.print(tracking)
        lost = objects_table(results)
        if lost is not None:
            console.print(lost)
        for note in notes(results):
            console.print(f"[yellow]note: {note}")
        if args.renders is not None:
            console.print(f"renders:    {args.renders.resolve()}")
        for plot in results.get("plots", []):
            console.print(f"plot:       {Path(plot).resolve()}")
        if args.checkpoint_dir is not None:
            ckpts = sorted(args.checkpoint_dir.glob("*.ckpt"))
            console.print(f"checkpoint: {ckpts[-1].resolve() if ckpts else args.checkpoint_dir}")
        console.print(f"metrics:    {args.eval_json.resolve()}")

    run_cli(run)


if __name__ == "__main__":
    main()
