"""Speed against accuracy: train and evaluate points of the preset family on built-in streets and
write the table and the Pareto plot (time against PSNR and DPSNR).

A point is a step count with the preset's schedules scaled to it, as ``idsplat-fast`` scales them
(``make_trainer_config``: resolution schedule at 1/5 and 7/15 of the run, warm-ups in proportion),
plus optional overrides of the model config (one knob moved at a time). Each training runs in a
child process of its own and is measured there: wall time, CPU time (user + system, the figure
least disturbed by other work on the machine) and peak resident memory. The street's instance
preprocessing runs once before the points (``idsplat-preprocess``, timed apart) so that every
point reads it from the cache. Then ``ns-eval``: PSNR, SSIM, DPSNR, MOTA@2m, lidar depth error
(``lidar_depth``: median squared range error, m^2), and the Gaussians in the final checkpoint.

    .venv/bin/python -m bench.pareto --seeds 100 --work outputs/pareto --table docs/pareto_table.md --plot docs/reports/2026-11-27-pareto.png
    .venv/bin/python -m bench.pareto --points steps-300 steps-1000 --seeds 100 101 --work W

Each training and evaluation runs on ``--threads`` threads (default 1: ``OMP_NUM_THREADS`` in their
environment, which torch and the compiled compositor follow), so that several can share the
machine and their CPU times compare.

On a GPU (trainings follow nerfstudio's ``--machine.device-type``, CUDA where there is one) the
table adds the device and the peak GPU memory, and the front and the plot put wall time on the
time axis. Where instance preprocessing cannot run (open3d missing), ``--import-tracks DIR`` reads
each street's tracks from ``DIR/<street>.json``, written elsewhere by
``idsplat-preprocess --data STREET --export DIR/<street>.json``; ``--camera-backend torch`` trains
with the pure-torch camera rasterizer where gsplat has not been compiled:

    python -m bench.pareto --seeds 100 --import-tracks tracks --camera-backend torch --points "steps-1500 (idsplat-fast)"

Results are stored per (street, point) in ``WORK/<street>/<point>/``; a point whose result.json
exists is read, not trained again.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# The project's commands as modules of this Python: they run where the project is importable but its
# console scripts are not installed (a GPU machine with the project on PYTHONPATH).
SYNTH = [sys.executable, "-m", "idsplat_ns.data.synthetic.cli"]
PREPROCESS = [sys.executable, "-m", "idsplat_ns.cli.preprocess"]
NS_EVAL = [sys.executable, "-c", "import sys; from nerfstudio.scripts.eval import entrypoint; sys.argv[0] = 'ns-eval'; entrypoint()"]

# name: (steps, {dotted model-config field: value}). Knobs move one at a time around 600 and 1000 steps
# and around the presets.
HALF_INITIAL = {"pipeline.model.num_random_points": 10_000, "pipeline.model.max_lidar_points": 30_000}
POINTS: dict[str, tuple[int, dict]] = {
    "steps-300": (300, {}),
    "steps-600": (600, {}),
    "steps-1000": (1000, {}),
    "steps-1500 (idsplat-fast)": (1500, {}),
    "steps-3000 (idsplat-medium)": (3000, {}),
    "steps-1000, lidar every step": (1000, {"pipeline.model.lidar.every_n_steps": 1}),
    "steps-1000, half initial Gaussians": (1000, HALF_INITIAL),
    "steps-600, half initial Gaussians": (600, HALF_INITIAL),
    "steps-1000, Gaussian cap x1.5": (1000, {"pipeline.model.cap_factor": 1.5}),
    # around the presets: between idsplat-fast and idsplat-medium, and idsplat-fast from fewer Gaussians
    "steps-2000": (2000, {}),
    "steps-1500, half initial Gaussians": (1500, HALF_INITIAL),
    # the resolution schedule of idsplat-fast ((300, 700): 1/4 size, then 1/2, full from step 700)
    # moved both ways: full size from the first step, and each size held twice as long
    "steps-1500, full resolution throughout": (1500, {"pipeline.model.resolution_schedule": ()}),
    "steps-1500, resolution schedule x2": (1500, {"pipeline.model.resolution_schedule": (600, 1400)}),
}
DEFAULT_POINTS = ["steps-300", "steps-600", "steps-1000", "steps-1500 (idsplat-fast)",
                  "steps-1000, lidar every step", "steps-1000, half initial Gaussians"]


def point_config(steps: int, overrides: dict):
    """The trainer configuration of a point: ``ns-train idsplat-fast`` with ``steps`` (schedules
    scaled with the run) and the ``overrides`` (dotted config field: value)."""
    from method_configs.idsplat import make_trainer_config

    cfg = make_trainer_config("idsplat-fast", steps, (max(1, steps // 5), max(2, steps * 7 // 15)), fast=True)
    for path, value in overrides.items():
        *parents, name = path.split(".")
        target = cfg
        for p in parents:
            target = getattr(target, p)
        if not hasattr(target, name):
            raise SystemExit(f"pareto.py: no config field {path}")
        setattr(target, name, value)
    return cfg


def train_point(street: Path, out: Path, steps: int, overrides: dict) -> None:
    """The child process: one training, as ``ns-train idsplat-fast`` with ``steps`` would run it.
    Prints ``DEVICE {json}``: the device trained on and, on CUDA, its peak allocated memory."""
    import torch
    from nerfstudio.scripts.train import _set_random_seed

    cfg = point_config(steps, overrides)
    if cfg.pipeline.datamanager.import_tracks is not None:
        cfg.pipeline.datamanager.import_tracks = Path(cfg.pipeline.datamanager.import_tracks)
    cfg.pipeline.datamanager.dataparser.data = street
    cfg.vis = "tensorboard"
    cfg.output_dir = out
    cfg.experiment_name = "point"
    cfg.timestamp = "run"
    cfg.save_config()
    _set_random_seed(cfg.machine.seed)
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    device = {"device": "cpu"}
    if cfg.machine.device_type == "cuda":
        device = {"device": torch.cuda.get_device_name(0), "peak_gpu_gib": torch.cuda.max_memory_allocated() / 2**30}
    print("DEVICE " + json.dumps(device), flush=True)


def threads_env(threads: int) -> dict:
    """This process's environment with ``threads`` threads for torch (and so the compiled compositor)."""
    return {**os.environ, "OMP_NUM_THREADS": str(threads)}


def measured(cmd: list[str], threads: int) -> dict:
    """Run ``cmd`` (printed first, must succeed) on ``threads`` threads; its wall time, CPU time and peak RSS.
    Peak RSS comes from a wrapper process whose only child is ``cmd``."""
    print("$ " + " ".join(cmd), flush=True)
    wrapper = ("import json, resource, subprocess, sys, time; t = time.perf_counter(); "
               "rc = subprocess.run(sys.argv[1:]).returncode; w = time.perf_counter() - t; "
               "u = resource.getrusage(resource.RUSAGE_CHILDREN); "
               "print('MEASURED ' + json.dumps({'rc': rc, 'wall_s': w, 'cpu_s': u.ru_utime + u.ru_stime, "
               "'peak_rss_gib': u.ru_maxrss / 2**20}))")
    done = subprocess.run([sys.executable, "-c", wrapper, *cmd], capture_output=True, text=True,
                          env=threads_env(threads))
    sys.stdout.write(done.stdout[-2000:])
    line = [x for x in done.stdout.splitlines() if x.startswith("MEASURED ")]
    if done.returncode or not line or json.loads(line[-1][9:])["rc"]:
        raise SystemExit(f"pareto.py: failed: {' '.join(cmd)}\n{done.stderr[-3000:]}")
    device = [x for x in done.stdout.splitlines() if x.startswith("DEVICE ")]
    return json.loads(line[-1][9:]) | (json.loads(device[-1][7:]) if device else {})


def final_gaussians(run_dir: Path) -> int:
    import torch

    ckpt = sorted((run_dir / "nerfstudio_models").glob("step-*.ckpt"))[-1]
    state = torch.load(ckpt, map_location="cpu", weights_only=True)["pipeline"]
    return int(next(v.shape[0] for k, v in state.items() if k.endswith("gaussians.means")))




def run_point(street: Path, work: Path, name: str, threads: int, setup: dict | None = None) -> dict:
    """Train and evaluate one point (or read its result.json). ``setup``: dotted config fields set
    for every point (instance tracks, camera backend), not part of the point's name."""
    steps, overrides = POINTS[name]
    overrides = {**overrides, **(setup or {})}
    out = work / name.replace(" ", "_").replace(",", "").replace("(", "").replace(")", "")
    result_file = out / "result.json"
    if result_file.is_file():
        return json.loads(result_file.read_text())
    out.mkdir(parents=True, exist_ok=True)
    job = json.dumps([str(street), str(out), steps, overrides])
    cost = measured([sys.executable, "-m", "bench.pareto", "--train-one", job], threads)
    run_dir = out / "point" / "idsplat-fast" / "run"
    subprocess.run([*NS_EVAL, "--load-config", str(run_dir / "config.yml"), "--output-path",
                    str(out / "eval.json")], check=True, capture_output=True, env=threads_env(threads))  # fmt: skip
    r = json.loads((out / "eval.json").read_text())["results"]
    row = {"point": name, "steps": steps, **cost, "psnr": r.get("psnr"), "ssim": r.get("ssim"), "dpsnr": r.get("dpsnr"),
           "mota@2m": r.get("mota@2m"), "lidar_depth": r.get("lidar_depth_median_sq_err"), "gaussians": final_gaussians(run_dir)}
    result_file.write_text(json.dumps(row, indent=1))
    return row


def time_key(rows: list[dict]) -> str:
    """The time the front is drawn against: CPU time (least disturbed by other work), or wall time
    where the rows trained on a GPU (the CPU then mostly waits on it)."""
    return "wall_s" if any(r.get("device", "cpu") != "cpu" for r in rows) else "cpu_s"


def pareto_front(rows: list[dict], key: str) -> list[dict]:
    """Rows not beaten by another row that is both faster (``time_key``) and better in ``key``."""
    t = time_key(rows)
    return [r for r in rows if not any(o[t] < r[t] and (o[key] or -math.inf) > (r[key] or -math.inf)
                                       for o in rows)]


def table(rows: list[dict]) -> str:
    cols = [("street", "{}"), ("point", "{}"), ("wall_s", "{:.0f}"), ("cpu_s", "{:.0f}"), ("peak_rss_gib", "{:.2f}"),
            ("psnr", "{:.2f}"), ("ssim", "{:.3f}"), ("dpsnr", "{:.2f}"), ("mota@2m", "{:.3f}"),
            ("lidar_depth", "{:.3f}"), ("gaussians", "{:,}")]  # fmt: skip
    if time_key(rows) == "wall_s":
        cols += [("device", "{}"), ("peak_gpu_gib", "{:.1f}")]
    lines = ["| " + " | ".join(c for c, _ in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join("-" if r.get(c) is None else f.format(r[c]) for c, f in cols) + " |")
    return "\n".join(lines)


def summary(rows: list[dict]) -> str:
    """Per point, over the streets that ran it: mean time (``time_key``), PSNR, DPSNR and lidar
    depth, and on how many streets the point is on that street's front (PSNR and DPSNR against time)."""
    t = time_key(rows)
    streets = sorted({r["street"] for r in rows})
    fronts = {(s, k): {id(r) for r in pareto_front([r for r in rows if r["street"] == s], k)}
              for s in streets for k in ("psnr", "dpsnr")}  # fmt: skip
    lines = [f"| point | streets | mean {t} | mean psnr | mean dpsnr | mean lidar_depth | on the PSNR front | on the DPSNR front |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for point in dict.fromkeys(r["point"] for r in rows):
        mine = [r for r in rows if r["point"] == point]

        def mean(key: str, fmt: str) -> str:
            vals = [r[key] for r in mine if r.get(key) is not None]
            return fmt.format(sum(vals) / len(vals)) if vals else "-"

        on = {k: sum(id(r) in fronts[(r["street"], k)] for r in mine) for k in ("psnr", "dpsnr")}
        lines.append(f"| {point} | {len(mine)} | {mean(t, '{:.0f}')} | {mean('psnr', '{:.2f}')} | "
                     f"{mean('dpsnr', '{:.2f}')} | {mean('lidar_depth', '{:.3f}')} | {on['psnr']}/{len(mine)} | "
                     f"{on['dpsnr']}/{len(mine)} |")  # fmt: skip
    return "\n".join(lines)


def point_means(rows: list[dict], key: str) -> dict[str, tuple[float, float]]:
    """Per point, in time order: (mean seconds (``time_key``), mean ``key``) over the streets that have both."""
    t = time_key(rows)
    means = {}
    for point in dict.fromkeys(r["point"] for r in rows):
        mine = [r for r in rows if r["point"] == point and r.get(key) is not None]
        if mine:
            means[point] = (sum(r[t] for r in mine) / len(mine), sum(r[key] for r in mine) / len(mine))
    return dict(sorted(means.items(), key=lambda kv: kv[1][0]))


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    several = len({r["street"] for r in rows}) > 1
    t = time_key(rows)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, key, label in zip(axes, ("psnr", "dpsnr"), ("PSNR (dB)", "DPSNR (dB)")):
        labelled = []  # (minutes, dB, point): each point once, at its mean where there are several streets
        for street in sorted({r["street"] for r in rows}):
            mine = [r for r in rows if r["street"] == street and r.get(key) is not None]
            ax.scatter([r[t] / 60 for r in mine], [r[key] for r in mine], s=18 if several else 36, label=street)
            front = sorted(pareto_front(mine, key), key=lambda r: r[t])
            ax.plot([r[t] / 60 for r in front], [r[key] for r in front], "--", lw=1)
            if not several:
                labelled += [(r[t] / 60, r[key], r["point"]) for r in mine]
        means = point_means(rows, key)
        if several:
            ax.plot([m[0] / 60 for m in means.values()], [m[1] for m in means.values()], "k-o", lw=1.5, ms=5,
                    label="mean over streets")  # fmt: skip
            labelled = [(t / 60, q, point) for point, (t, q) in means.items()]
        for minutes, value, point in labelled:
            ax.annotate(point.replace("steps-", ""), (minutes, value), fontsize=7, xytext=(4, -10),
                        textcoords="offset points")  # fmt: skip
        ax.margins(x=0.2)  # room for the labels of the longest runs
        ax.set_xlabel("training CPU time (min)" if t == "cpu_s" else f"training wall time (min), {rows[0]['device']}")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Speed against accuracy (dashed: each street's Pareto front; black: the mean of each point)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--train-one", help=argparse.SUPPRESS)
    ap.add_argument("--preset", default="small", help="built-in street preset")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100])
    ap.add_argument("--points", nargs="+", default=DEFAULT_POINTS, choices=list(POINTS))
    ap.add_argument("--work", type=Path, default=REPO / "outputs" / "pareto")
    ap.add_argument("--table", type=Path, default=None, help="also write the markdown table here")
    ap.add_argument("--plot", type=Path, default=None, help="write the Pareto plot (PNG) here")
    ap.add_argument("--threads", type=int, default=1, help="threads of each training and evaluation")
    ap.add_argument("--import-tracks", type=Path, default=None, metavar="DIR",
                    help="read each street's instance tracks from DIR/<street>.json (idsplat-preprocess --export) "
                         "instead of preprocessing it here")  # fmt: skip
    ap.add_argument("--camera-backend", choices=["auto", "gsplat", "torch"], default="auto",
                    help="--pipeline.model.camera-backend of every training")
    args = ap.parse_args()
    if args.threads < 1:
        raise SystemExit(f"pareto.py: --threads {args.threads}: give 1 or more")
    if args.train_one:
        street, out, steps, overrides = json.loads(args.train_one)
        train_point(Path(street), Path(out), int(steps), overrides)
        return
    rows = []
    for seed in args.seeds:
        name = f"synth_{args.preset}_{seed}"
        street = args.work / "streets" / name
        setup = {"pipeline.model.camera_backend": args.camera_backend}
        if args.import_tracks is not None:
            tracks = (args.import_tracks / f"{name}.json").resolve()
            if not tracks.is_file():
                raise SystemExit(f"pareto.py: --import-tracks: no {tracks}; write it with "
                                 f"idsplat-preprocess --data {street} --export {tracks}")  # fmt: skip
            setup["pipeline.datamanager.import_tracks"] = str(tracks)  # a Path again in the child
        if not street.is_dir():
            subprocess.run([*SYNTH, "--preset", args.preset, "--seed", str(seed), "--out",
                            str(args.work / "streets"), "--quiet"], check=True)  # fmt: skip
        if args.import_tracks is None:
            prep_file = args.work / name / "preprocess.json"
            if not prep_file.is_file():
                prep_file.parent.mkdir(parents=True, exist_ok=True)
                prep = measured([*PREPROCESS, "--data", str(street)], args.threads)
                prep_file.write_text(json.dumps(prep))
            prep = json.loads(prep_file.read_text())
            print(f"{name}: preprocessing {prep['wall_s']:.0f} s wall, {prep['cpu_s']:.0f} s CPU", flush=True)
        for point in args.points:
            rows.append({"street": name, **run_point(street, args.work / name, point, args.threads, setup)})
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    text = table(rows)
    if len({r["street"] for r in rows}) > 1:
        text += "\n\n" + summary(rows)
    print("\n" + text)
    if args.table:
        args.table.write_text(text + "\n")
    if args.plot:
        plot(rows, args.plot)
        print("wrote", args.plot)


if __name__ == "__main__":
    main()
