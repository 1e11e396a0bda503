"""Print an ``ns-eval`` result as a table, with where the renders and checkpoint are."""

from __future__ import annotations

import argparse
import json
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
    ("all_mota@2m", "tracking MOTA @ 2 m (all annotated, seen or not)"),
    ("lidar_depth_median_sq_err", "lidar depth median squared error (m^2)"),
    ("lidar_intensity_rmse", "lidar intensity RMSE"),
    ("lidar_raydrop_acc", "lidar ray-drop accuracy"),
    ("lidar_chamfer", "lidar Chamfer distance (m)"),
    ("render_mpix_per_s", "render speed (MP/s)"),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("eval_json", type=Path)
    parser.add_argument("--renders", type=Path, default=None)
    parser.add_argument("--checkpoint-dir", type=Path, default=None)
    args = parser.parse_args()

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
        console.print(table)
        if "lpips_note" in results:
            console.print(f"[yellow]{results['lpips_note']}")
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
