"""The three instance modes side by side on a synthetic street: trains each with ``ns-train``,
evaluates with ``ns-eval`` and prints one table (image, dynamic-region, tracking and lidar
metrics, training wall time).

    .venv/bin/python bench/bench_modes.py --preset small --seed 1 --steps 1500

Each run is the plain command line a user would type (printed before it starts), so every figure
of the table can be reproduced one by one.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent
COLUMNS = (
    ("psnr", "PSNR"), ("ssim", "SSIM"), ("dpsnr", "DPSNR"), ("mota@2m", "MOTA@2m"), ("motp@2m", "MOTP@2m"),
    ("recall@2m", "recall@2m"), ("all_mota@2m", "MOTA@2m (all)"), ("lidar_depth_median_sq_err", "depth med. sq. err"),
    ("lidar_intensity_rmse", "intensity RMSE"), ("lidar_raydrop_acc", "ray-drop acc."), ("lidar_chamfer", "Chamfer"),
)


def _run(cmd: list[str]) -> float:
    print("$ " + " ".join(cmd), flush=True)
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    return time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small", help="built-in street preset (tiny, small, bench)")
    ap.add_argument("--seed", type=int, default=0, help="built-in street seed")
    ap.add_argument("--steps", type=int, default=1500, help="training steps of each mode (idsplat-fast)")
    ap.add_argument("--modes", nargs="+", default=["static", "self-supervised", "oracle"])
    ap.add_argument("--output-dir", type=Path, default=Path("outputs/bench_modes"))
    ap.add_argument("--skip-existing", action="store_true", help="reuse runs whose eval.json exists")
    ap.add_argument("--train-args", default="", help="extra ns-train options, one string (e.g. "
                    "\"--optimizers.trajectory-positions.optimizer.lr 1e-2\")")
    args = ap.parse_args()
    rows = {}
    for mode in args.modes:
        name = f"{args.preset}-{args.seed}-{mode}"
        run_dir = args.output_dir / name / "idsplat-fast" / "run"
        eval_json = args.output_dir / name / "eval.json"
        train_s = float("nan")
        if not (args.skip_existing and eval_json.is_file()):
            train_s = _run([
                str(BIN / "ns-train"), "idsplat-fast", "--vis", "tensorboard", "--output-dir", str(args.output_dir),
                "--experiment-name", name, "--timestamp", "run", "--max-num-iterations", str(args.steps),
                "--pipeline.datamanager.instance-mode", mode, *shlex.split(args.train_args),
                "idsplat-builtin", "--preset", args.preset, "--seed", str(args.seed),
            ])
            _run([str(BIN / "ns-eval"), "--load-config", str(run_dir / "config.yml"), "--output-path", str(eval_json)])
        results = json.loads(eval_json.read_text())["results"]
        results["train_s"] = train_s
        rows[mode] = results
    header = ["mode"] + [title for _, title in COLUMNS] + ["train wall s"]
    print("\n| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for mode, r in rows.items():
        cells = [mode] + [f"{r[k]:.3f}" if k in r else "-" for k, _ in COLUMNS] + [f"{r['train_s']:.0f}"]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
