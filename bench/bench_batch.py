"""Overhead of ``idsplat-batch`` over running the same sequences by hand, one after the other.

By hand is what a user types per sequence: ``ns-train`` (which preprocesses itself) then
``ns-eval``. The batch runs the same sequences with the same ns-train options through Ray
(preprocessing, training and evaluation as separate tasks, a local Ray started by the command).
Each arm gets a fresh instance cache, so both compute the preprocessing. The arms alternate, and
the table gives each repeat's wall times and their ratio (batch / by hand), then the median.

    .venv/bin/python -m bench.bench_batch --streets 3 --steps 5 --repeats 2

Prints the table; ``--markdown`` prints it as a Markdown table for docs/reports/2026-11-27-batch-overhead.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from idsplat_ns.batch.commands import RUN_TIMESTAMP, eval_command, split_user_options, train_command
from idsplat_ns.batch.sequences import Sequence

from bench.train_variants import installed

METHOD = "idsplat-fast"
SMALL = ["--pipeline.model.num-random-points", "2000", "--pipeline.model.max-lidar-points", "8000"]


def _timed(cmd: list[str], env: dict[str, str], log: Path) -> float:
    start = time.perf_counter()
    with open(log, "ab") as out:
        code = subprocess.run(cmd, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    seconds = time.perf_counter() - start
    # Exit status 0 for the hand arm; the batch's is its number of failed sequences.
    if code != 0:
        raise SystemExit(f"error: {cmd[0]} exited with {code}; see {log}")
    return seconds


def by_hand(streets: list[Path], options: list[str], work: Path) -> float:
    """ns-train then ns-eval per street, one after the other; total wall time."""
    env = {**os.environ, "IDSPLAT_CACHE": str(work / "cache")}
    out = work / "out"
    total = 0.0
    for street in streets:
        train = train_command(Sequence(street.name, street), METHOD, split_user_options(list(options)), out)
        total += _timed(installed(train), env, work / "hand.log")
        config = out / street.name / METHOD / RUN_TIMESTAMP / "config.yml"
        evaluate = eval_command(config, out / f"{street.name}.json")
        total += _timed(installed(evaluate), env, work / "hand.log")
    return total


def batch(streets: list[Path], options: list[str], work: Path, num_cpus: int) -> float:
    """idsplat-batch over the streets; total wall time (Ray's start included)."""
    env = {**os.environ, "IDSPLAT_CACHE": str(work / "cache")}
    listing = work / "sequences.txt"
    listing.write_text("".join(f"{s}\n" for s in streets))
    return _timed(installed(["idsplat-batch", "--sequences", str(listing), "--output-dir", str(work / "out"),
                   "--method", METHOD, "--num-cpus", str(num_cpus), *options]), env, work / "batch.log")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--streets", type=int, default=3, help="tiny streets (seeds 0..N-1)")
    ap.add_argument("--steps", type=int, default=5, help="training steps per street")
    ap.add_argument("--repeats", type=int, default=2, help="times each arm runs (alternating)")
    ap.add_argument("--num-cpus", type=int, default=os.cpu_count() or 1, help="the batch's local Ray cores")
    ap.add_argument("--work", type=Path, default=None, help="folder for streets and runs (default: temporary, removed)")
    ap.add_argument("--markdown", action="store_true", help="print the table as Markdown")
    args = ap.parse_args()

    from idsplat_ns.data.synthetic import generate_sequence

    work = args.work or Path(tempfile.mkdtemp(prefix="bench_batch_"))
    streets = [Path(generate_sequence(work / "streets", preset="tiny", seed=s, progress=False)) for s in range(args.streets)]
    options = ["--max-num-iterations", str(args.steps), *SMALL]
    rows = []
    try:
        for r in range(args.repeats):
            arms = [("hand", by_hand), ("batch", batch)]
            if r % 2:
                arms.reverse()  # alternate, so that a drift in the machine's load hits both arms
            times = {}
            for name, fn in arms:
                run_dir = work / f"r{r}-{name}"
                shutil.rmtree(run_dir, ignore_errors=True)
                run_dir.mkdir(parents=True)
                times[name] = (fn(streets, options, run_dir, args.num_cpus) if name == "batch"
                               else fn(streets, options, run_dir))
                print(f"repeat {r + 1}: {name} {times[name]:.1f} s", flush=True)
            rows.append((r + 1, times["hand"], times["batch"], times["batch"] / times["hand"]))
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)

    median = statistics.median(row[3] for row in rows)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    machine = f"{platform.machine()}, {os.cpu_count()} cores, load average {load:.1f} at the end"
    command = "python -m bench.bench_batch " + " ".join(sys.argv[1:])
    if args.markdown:
        print(f"\n`{command}` ({args.streets} tiny streets, {args.steps} steps; {machine})\n")
        print("| repeat | by hand [s] | idsplat-batch [s] | ratio |\n|---:|---:|---:|---:|")
        for r, hand, bat, ratio in rows:
            print(f"| {r} | {hand:.1f} | {bat:.1f} | {ratio:.2f} |")
        print(f"| median | | | **{median:.2f}** |")
    else:
        print(f"\n{command}: {args.streets} tiny streets, {args.steps} steps; {machine}")
        print(f"{'repeat':>6} {'by hand [s]':>12} {'batch [s]':>10} {'ratio':>6}")
        for r, hand, bat, ratio in rows:
            print(f"{r:>6} {hand:>12.1f} {bat:>10.1f} {ratio:>6.2f}")
        print(f"median ratio (batch / by hand): {median:.2f}")


if __name__ == "__main__":
    main()
