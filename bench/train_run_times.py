"""Step times, peak GPU memory and ns-eval results of the whole trainings that
``bench/gpu_ns_train.sh`` runs, as one table (``step_times.md``, ``step_times.json``).

    python -m bench.train_run_times LOGS --steps 100 400 --out OUT

``LOGS`` holds one folder per training, each with ``run.json`` (engine, camera backend, start and
end in epoch seconds), the training's tensorboard events (nerfstudio's ``Train Iter (time)``,
logged for every step when ``--logging.max-buffer-size 1``: each value is then that step's own
wall time, not a running mean) and, where ns-eval ran, ``eval.json``; ``LOGS/gpu_memory.txt`` has
nvidia-smi samples (epoch seconds, MiB used), of which each training's peak is the largest inside
its start and end.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

STEP_TIME_TAG = "Train Iter (time)"
ALLOCATED_TAG = "GPU Memory (MB)"  # torch.cuda.max_memory_allocated, logged every steps_per_log steps
EVAL_COLUMNS = (("psnr", "PSNR"), ("ssim", "SSIM"), ("dpsnr", "DPSNR"), ("lidar_depth_median_sq_err", "lidar depth m²"))


def scalars(events_dir: Path, tags: tuple[str, ...]) -> dict[str, dict[int, float]]:
    """Per tag, step -> value of that scalar, from a training's tensorboard events files (each
    file read once for all tags)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    values: dict[str, dict[int, float]] = {tag: {} for tag in tags}
    for path in sorted(events_dir.glob("events.out.tfevents.*")):
        acc = EventAccumulator(str(path), size_guidance={"scalars": 0})
        acc.Reload()
        logged = acc.Tags().get("scalars", [])
        for tag in tags:
            if tag in logged:
                values[tag].update({e.step: e.value for e in acc.Scalars(tag)})
    return values


def peak_memory_mib(samples: list[tuple[int, int]], start: int, end: int) -> int | None:
    inside = [mib for t, mib in samples if start <= t <= end]
    return max(inside) if inside else None


def read_samples(path: Path) -> list[tuple[int, int]]:
    samples = []
    if path.exists():
        for line in path.read_text().splitlines():
            parts = line.split()
            if len(parts) == 2 and parts[0].isdigit() and parts[1].isdigit():
                samples.append((int(parts[0]), int(parts[1])))
    return samples


def summarise(logs: Path, first: int, last: int) -> list[dict]:
    samples = read_samples(logs / "gpu_memory.txt")
    rows = []
    runs = sorted(((json.loads(p.read_text()), p.parent) for p in logs.glob("*/run.json")), key=lambda r: r[0]["start"])
    for run, folder in runs:
        logged = scalars(folder, (STEP_TIME_TAG, ALLOCATED_TAG))
        seconds, allocated = logged[STEP_TIME_TAG], logged[ALLOCATED_TAG]
        window = [s for step, s in seconds.items() if first <= step <= last]
        deciles = statistics.quantiles(window, n=10) if len(window) >= 10 else [None]
        row = {**run, "steps_logged": len(seconds), "last_step": max(seconds, default=None),
               "steps_in_window": len(window),
               "median_step_s": statistics.median(window) if window else None,
               "p10_step_s": deciles[0], "p90_step_s": deciles[-1],
               "peak_gpu_mib": peak_memory_mib(samples, run["start"], run["end"]),
               "peak_allocated_mib": max(allocated.values(), default=None)}
        eval_file = folder / "eval.json"
        if eval_file.exists():
            evaluated = json.loads(eval_file.read_text())
            results = evaluated.get("results", {})
            row["eval"] = {key: results.get(key) for key, _ in EVAL_COLUMNS}
            row["eval_checkpoint"] = evaluated.get("checkpoint")
        rows.append(row)
    return rows


def _fmt(value, digits: int) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def table(rows: list[dict], first: int, last: int) -> str:
    head = ["training", "camera backend", f"median step s ({first}-{last})", "p10-p90 s", "steps in range",
            "peak GPU GiB (nvidia-smi / allocated)"] + [name for _, name in EVAL_COLUMNS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    base = rows[0]["median_step_s"] if rows and rows[0]["median_step_s"] else None
    for row in rows:
        med = row["median_step_s"]
        ratio = f" ({med / base:.2f}x)" if base and med else ""
        spread = f"{_fmt(row['p10_step_s'], 3)}-{_fmt(row['p90_step_s'], 3)}" if row["p10_step_s"] else ""
        peak, alloc = row["peak_gpu_mib"], row["peak_allocated_mib"]
        ev = row.get("eval", {})
        cells = [row["tag"], row["backend"], _fmt(med, 3) + ratio, spread, str(row["steps_in_window"]),
                 f"{_fmt(peak / 1024 if peak else None, 1)} / {_fmt(alloc / 1024 if alloc else None, 1)}"]
        cells += [_fmt(ev.get(key), 4 if key == "ssim" or key.startswith("lidar") else 2) for key, _ in EVAL_COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("logs", type=Path, help="the folder of the trainings (bench/gpu_ns_train.sh's OUT/logs)")
    parser.add_argument("--steps", type=int, nargs=2, default=(100, 400), metavar=("FROM", "TO"),
                        help="the steps whose median time is reported")
    parser.add_argument("--out", type=Path, required=True, help="folder for step_times.md and step_times.json")
    args = parser.parse_args()
    rows = summarise(args.logs, *args.steps)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "step_times.json").write_text(json.dumps(rows, indent=1))
    (args.out / "step_times.md").write_text(table(rows, *args.steps))


if __name__ == "__main__":
    main()
