"""``idsplat-batch``: preprocessing, training and evaluation of many sequences as Ray tasks.

Example::

    idsplat-batch --sequences seqs.txt --output-dir batch/ --method idsplat-fast --max-num-iterations 3000
    idsplat-batch --sequences pandaset-10 --data-root /data/pandaset --output-dir batch/ --method idsplat

Options it does not know are ns-train's and go to every training unchanged (method options, then
optionally a dataparser subcommand and its options). The exit status is the number of sequences
that failed (at most 100); 2 with an ``error:`` line when the batch itself cannot start, 130 when
interrupted. Reference: docs/batch.md.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Optional

from idsplat_ns.batch.commands import UserOptions, split_user_options, total_steps
from idsplat_ns.batch.layout import read_eval
from idsplat_ns.batch.sequences import load_sequences
from idsplat_ns.errors import IDSplatError

# torch (plan), matplotlib (aggregate) and Ray (runner) take 1.5-4 s to import on 2
# cores: they are imported where a batch runs, so that --help and option errors answer at once.
if TYPE_CHECKING:
    from rich.console import Console

    from idsplat_ns.batch.plan import SequencePlan
    from idsplat_ns.batch.runner import Outcome

MAX_EXIT_FAILURES = 100
"""Exit statuses above this are the shell's (126+: not executable, signals): the count is capped."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="idsplat-batch", allow_abbrev=False,  # abbreviations would swallow ns-train's options
        description="Preprocess, train and evaluate many sequences as Ray tasks, resumable, with one results table. "
                    "Other options are passed to ns-train.",
    )
    p.add_argument("--sequences", required=True,
                   help="a text file of sequences (a path a line, optionally a protocol and dataparser options) "
                        "or a protocol name (pandaset-10, streetgs, ...) with --data-root")
    p.add_argument("--output-dir", type=Path, required=True, help="folder that receives a folder per sequence and the table")
    p.add_argument("--method", default="idsplat", help="ns-train method (default: idsplat; idsplat-fast: the CPU preset)")
    p.add_argument("--data-root", type=Path, default=None, help="with a protocol name: the folder that holds its sequences")
    p.add_argument("--address", default=None,
                   help="an existing Ray cluster (ray://HOST:10001, HOST:6379 or auto); default: a local one for this command")
    p.add_argument("--num-cpus", type=int, default=None, help="local Ray: CPU cores it may use (default: all)")
    p.add_argument("--num-gpus", type=int, default=None, help="local Ray: GPUs it may use (default: those it finds)")
    p.add_argument("--object-store-mb", type=int, default=128, help="local Ray: object store size (default: 128)")
    for step, cpus, what in (("preprocess", 1.0, "preprocessing"), ("train", 1.0, "training"), ("eval", 1.0, "evaluation")):
        p.add_argument(f"--{step}-cpus", type=float, default=cpus, help=f"CPU cores per {what} task (default: {cpus:g})")
        gpu_default = "0" if step == "preprocess" else "1 where the cluster has GPUs, else 0"
        p.add_argument(f"--{step}-gpus", type=float, default=0.0 if step == "preprocess" else None,
                       help=f"GPUs per {what} task (default: {gpu_default})")
        p.add_argument(f"--{step}-memory-gb", type=float, default=0.0,
                       help=f"memory reserved per {what} task, GiB (default: 0, none declared)")
    return p


def _check_args(args: argparse.Namespace) -> None:
    for step in ("preprocess", "train", "eval"):
        for kind in ("cpus", "gpus", "memory_gb"):
            v = getattr(args, f"{step}_{kind}")
            if v is not None and v < 0:
                raise IDSplatError(f"--{step}-{kind.replace('_', '-')} {v:g}: must not be negative")
        if getattr(args, f"{step}_cpus") <= 0:
            raise IDSplatError(f"--{step}-cpus {getattr(args, f'{step}_cpus'):g}: must be positive")
    if args.object_store_mb < 75:
        raise IDSplatError(f"--object-store-mb {args.object_store_mb}: Ray needs at least 75")
    if args.output_dir.exists() and not args.output_dir.is_dir():
        raise IDSplatError(f"--output-dir {args.output_dir}: is a file; give a folder")


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, UserOptions]:
    """The batch's own options (checked) and the pass-through ns-train options, split at the
    dataparser subcommand; one-line :class:`IDSplatError` for an option the batch owns."""
    args, rest = _parser().parse_known_args(argv)
    if rest[:1] == ["--"]:
        rest = rest[1:]
    _check_args(args)
    return args, split_user_options(rest)


def run_batch(argv: list[str]) -> int:
    """Parse ``argv``, run the batch, write and print the table; returns the number of failures."""
    from rich.console import Console

    from idsplat_ns.batch.plan import plan_sequence
    from idsplat_ns.batch.ray_cluster import RayStart
    from idsplat_ns.batch.runner import Outcome, Reporter, StepResources, run_on_ray

    args, user = parse_args(argv)
    sequences = load_sequences(args.sequences, args.data_root)
    output_dir = args.output_dir.expanduser().resolve()
    output_dir.mkdir(parents=True, exist_ok=True)

    steps_cache: list[int] = []

    def total() -> int:  # looked up once, only if some sequence has a checkpoint
        if not steps_cache:
            steps_cache.append(total_steps(args.method, user))
        return steps_cache[0]

    plans = [plan_sequence(s, args.method, user, output_dir, total) for s in sequences]
    resources = {step: StepResources(getattr(args, f"{step}_cpus"), getattr(args, f"{step}_gpus"),
                                     getattr(args, f"{step}_memory_gb")) for step in ("preprocess", "train", "eval")}
    # The steps' subprocesses read the stage cache from here; a cluster's nodes get the driver's.
    env = {k: os.environ[k] for k in ("IDSPLAT_CACHE",) if k in os.environ}

    # Piped output (a log file, a CI job) gets wide lines instead of rich's 80 columns.
    console = Console(highlight=False, width=None if sys.stdout.isatty() else 200)
    n_steps = sum(len(p.steps) for p in plans)
    console.print(f"idsplat-batch: {len(plans)} sequences, {n_steps} steps to run, method {args.method}, "
                  f"output {output_dir}", markup=False)
    if n_steps == 0:  # everything is evaluated: the table alone, without starting Ray
        outcome = Outcome(skipped=[p.sequence.name for p in plans])
        reporter = Reporter(output_dir / "batch.log", lambda msg: console.print(msg, markup=False))
        for p in plans:
            reporter.line(p.sequence.name, "skipped, already evaluated (eval.json)")
    else:
        ray_start = RayStart(args.address, args.num_cpus, args.num_gpus, args.object_store_mb)
        outcome = run_on_ray(plans, ray_start, resources, env, console, output_dir / "batch.log", n_steps)
    return _report(plans, outcome, args.method, output_dir, console)


def _report(plans: list[SequencePlan], outcome: Outcome, method: str, output_dir: Path, console: Console) -> int:
    """Write and print the table of every evaluated sequence of the list, list the failures;
    returns the number of failures."""
    from idsplat_ns.batch import aggregate

    rows = [aggregate.sequence_row(p.sequence.name, p.sequence.protocol, r) for p in plans
            if (r := read_eval(p.paths)) is not None]
    if rows:
        table_rows = aggregate.with_means(rows)
        csv_path = aggregate.write_csv(table_rows, output_dir / f"{method}_results.csv")
        aggregate.print_table(table_rows, f"{method}: {len(rows)} of {len(plans)} sequences", console.print)
        plot = aggregate.plot_dpsnr(table_rows, output_dir / f"{method}_dpsnr.png", f"{method}: DPSNR per sequence")
        console.print(f"table: {csv_path}" + (f"  plot: {plot}" if plot else "  (no DPSNR: no plot)"), markup=False)
    for name, error in outcome.failed.items():
        console.print(f"failed: {name}: {error}", markup=False)
    failed = f": {', '.join(outcome.failed)}" if outcome.failed else ""
    console.print(f"{len(outcome.done)} evaluated, {len(outcome.skipped)} skipped (already evaluated), "
                  f"{len(outcome.failed)} failed{failed}", markup=False)
    return len(outcome.failed)


def main(argv: Optional[list[str]] = None) -> None:
    """Console entry point: exit status = failed sequences (capped), 2 on a bad invocation, 130 on Ctrl-C."""
    try:
        failed = run_batch(sys.argv[1:] if argv is None else argv)
    except IDSplatError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    except KeyboardInterrupt:
        print("idsplat-batch: interrupted; run the same command again to continue", file=sys.stderr)
        raise SystemExit(130) from None
    raise SystemExit(min(failed, MAX_EXIT_FAILURES))


if __name__ == "__main__":
    main()
