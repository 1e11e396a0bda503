"""The instance modes side by side on built-in streets: trains each with ``ns-train``, evaluates
with ``ns-eval`` and prints one row per (street, mode) (image, dynamic-region, tracking and lidar
metrics, training wall time), then, per object name (the built-in street's manoeuvre), the frames
lost and the DPSNR of each mode from ns-eval's per-object diagnosis.

    .venv/bin/python -m bench.bench_modes --preset small --seeds 1 --steps 1500
    .venv/bin/python -m bench.bench_modes --preset hard --seeds 100 101 102 103 --modes self-supervised oracle \\
        --jobs 2 --out T.md

Each run is the plain command line a user would type (printed before it starts), so every figure
of the table can be reproduced one by one. With ``--jobs 2`` two runs train at once, each on one
thread (``OMP_NUM_THREADS=1``).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from idsplat_ns.batch.commands import eval_command, split_user_options, train_command
from idsplat_ns.batch.sequences import Sequence
from idsplat_ns.nerfstudio.builtin_scene import builtin_street

from bench.train_variants import installed

COLUMNS = (
    ("psnr", "PSNR"), ("ssim", "SSIM"), ("dpsnr", "DPSNR"), ("mota@2m", "MOTA@2m"), ("motp@2m", "MOTP@2m"),
    ("recall@2m", "recall@2m"), ("objects_frames_lost_near", "lost < 10 m"), ("objects_lost_over_3_frames", "gaps > 3"),
    ("all_mota@2m", "MOTA@2m (all)"), ("lidar_depth_median_sq_err", "depth med. sq. err"),
    ("lidar_chamfer", "Chamfer"),
)  # fmt: skip


def _run(cmd: list[str], env: dict) -> float:
    print("$ " + " ".join(cmd), flush=True)
    start = time.perf_counter()
    subprocess.run(cmd, check=True, env=env)
    return time.perf_counter() - start


def train_and_evaluate(preset: str, seed: int, mode: str, args: argparse.Namespace) -> dict:
    """ns-train then ns-eval of one (street, mode) (or the stored result with ``--skip-existing``)."""
    name = f"{preset}-{seed}-{mode}"
    run_dir = args.output_dir / name / "idsplat-fast" / "run"
    eval_json = args.output_dir / name / "eval.json"
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1") if args.jobs > 1 else dict(os.environ)
    train_s = float("nan")
    if not (args.skip_existing and eval_json.is_file()):
        # The built-in street as idsplat-pandaset reads it (the same reader as idsplat-builtin's).
        street = builtin_street(preset, seed)
        user = split_user_options(["--max-num-iterations", str(args.steps), "--pipeline.datamanager.instance-mode", mode,
                                   *shlex.split(args.train_args), "idsplat-pandaset"])
        train = train_command(Sequence(name, street), "idsplat-fast", user, args.output_dir)
        train_s = _run(installed(train), env)
        evaluate = eval_command(run_dir / "config.yml", eval_json)
        _run(installed(evaluate), env)
    results = json.loads(eval_json.read_text())["results"]
    results["train_s"] = train_s
    return results


def runs_table(rows: dict[tuple[int, str], dict]) -> str:
    header = ["street", "mode"] + [title for _, title in COLUMNS] + ["train wall s"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for (seed, mode), r in rows.items():
        cells = [str(seed), mode] + [f"{r[k]:.3f}" if k in r else "-" for k, _ in COLUMNS] + [f"{r['train_s']:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def manoeuvre_table(rows: dict[tuple[int, str], dict], modes: list[str]) -> str:
    """Per object name over the streets: frames lost (near the ego) and the mean DPSNR, per mode."""
    stats: dict[str, dict[str, list]] = {}
    for (_, mode), r in rows.items():
        for o in r.get("objects", []):
            s = stats.setdefault(f"{o['name']} ({o['class']})", {}).setdefault(mode, [0, 0, 0, 0, []])
            s[0] += o["frames_lost"]
            s[1] += o["frames"]
            s[2] += o["frames_lost_near"]
            s[3] += o["frames_near"]
            if o["dpsnr"] is not None:
                s[4].append(o["dpsnr"])
    header = ["object"] + [f"{m}: lost (< 10 m)" for m in modes] + [f"{m}: DPSNR" for m in modes]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name, by_mode in sorted(stats.items()):
        lost = [f"{by_mode[m][0]}/{by_mode[m][1]} ({by_mode[m][2]}/{by_mode[m][3]})" if m in by_mode else "-" for m in modes]
        dpsnr = [f"{np.mean(by_mode[m][4]):.2f}" if m in by_mode and by_mode[m][4] else "-" for m in modes]
        lines.append("| " + " | ".join([name] + lost + dpsnr) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small", help="built-in street preset (tiny, small, bench, varied, hard)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="built-in street seeds")
    ap.add_argument("--steps", type=int, default=1500, help="training steps of each mode (idsplat-fast)")
    ap.add_argument("--modes", nargs="+", default=["static", "self-supervised", "oracle"])
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (each on one thread when more than 1)")
    ap.add_argument("--output-dir", type=Path, default=Path("outputs/bench_modes"))
    ap.add_argument("--skip-existing", action="store_true", help="reuse runs whose eval.json exists")
    ap.add_argument("--train-args", default="", help="extra ns-train options, one string (e.g. "
                    "\"--optimizers.trajectory-positions.optimizer.lr 1e-2\")")
    ap.add_argument("--out", type=Path, default=None, help="also write the tables here (markdown)")
    args = ap.parse_args()
    keys = [(seed, mode) for seed in args.seeds for mode in args.modes]
    for seed in args.seeds:  # once each, before the runs that share a street start at once
        builtin_street(args.preset, seed)
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = list(pool.map(lambda k: train_and_evaluate(args.preset, k[0], k[1], args), keys))
    rows = dict(zip(keys, results))
    text = "\n\n".join([f"`{args.preset}` streets {' '.join(map(str, args.seeds))}, idsplat-fast {args.steps} steps",
                        runs_table(rows), manoeuvre_table(rows, args.modes)])  # fmt: skip
    print("\n" + text)
    if args.out is not None:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
