"""Train and evaluate named variants of ``idsplat-fast`` on one street with the plain commands a
user would type (each printed before it runs; built by :mod:`idsplat_ns.batch.commands`, as
``idsplat-batch`` builds them), and print their results side by side. Shared by
``bench_sensor_fidelity``, ``bench_deformation``, ``bench_rig`` and ``bench_rule_dpsnr``."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from idsplat_ns.batch.commands import eval_command, split_user_options, train_command
from idsplat_ns.batch.sequences import Sequence

BIN = Path(sys.executable).parent


def installed(cmd: list[str]) -> list[str]:
    """``cmd`` with its program taken from this interpreter's environment (the project's venv)."""
    return [str(BIN / cmd[0]), *cmd[1:]]


def run(cmd: list[str]) -> float:
    """Run ``cmd`` (printed first); its wall time in seconds."""
    print("$ " + " ".join(cmd), flush=True)
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    return time.perf_counter() - start


def synth_street(data_dir: Path, preset: str, seed: int, *extra: str) -> None:
    """``idsplat-synth`` into ``data_dir`` (a cache hit when the street exists)."""
    run(installed(["idsplat-synth", "--preset", preset, "--seed", str(seed), *extra, "--out", str(data_dir), "--quiet"]))


def train_and_evaluate(street: Path, name: str, output_dir: Path, steps: int, options: list[str], train_args: str = "",
                       skip_existing: bool = False, after_data: list[str] = ()) -> dict:
    """``ns-train idsplat-fast`` with ``options`` into ``output_dir/name``, then ``ns-eval``; the
    results of eval.json plus ``train_s`` (training wall time). ``after_data`` follows the
    dataparser's ``--data`` (the subcommands of optional configs, such as the smoothing's, and their
    options). With ``skip_existing`` a run whose eval.json exists is read, not repeated."""
    run_dir = output_dir / name / "idsplat-fast" / "run"
    eval_json = output_dir / name / "eval.json"
    timing = output_dir / name / "train_seconds.json"
    if not (skip_existing and eval_json.is_file()):
        if not (skip_existing and timing.is_file() and (run_dir / "config.yml").is_file()):
            user = split_user_options(["--max-num-iterations", str(steps), *options, *shlex.split(train_args),
                                       "idsplat-pandaset", *after_data])
            train_s = run(installed(train_command(Sequence(name, street), "idsplat-fast", user, output_dir)))
            timing.write_text(json.dumps({"train_s": train_s}))
        run(installed(eval_command(run_dir / "config.yml", eval_json)))
    results = json.loads(eval_json.read_text())["results"]
    results["train_s"] = json.loads(timing.read_text())["train_s"] if timing.is_file() else float("nan")
    return results


def mean_rows(per_seed: dict[str, list[dict]]) -> dict[str, dict]:
    """Per variant, the mean over streets of every number all its streets have."""
    means = {}
    for variant, results in per_seed.items():
        keys = set.intersection(*(set(r) for r in results))
        means[variant] = {k: float(np.mean([r[k] for r in results])) for k in keys if isinstance(results[0][k], (int, float))}
    return means


def print_table(rows: dict[str, dict], columns: tuple[tuple[str, str], ...], first: str = "variant") -> None:
    """A markdown table: one row per entry of ``rows``, the ``columns`` (key, title), training time."""
    header = [first] + [title for _, title in columns] + ["train wall s"]
    print("\n| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for name, r in rows.items():
        cells = [name] + [f"{r[k]:.3f}" if k in r else "-" for k, _ in columns] + [f"{r['train_s']:.0f}"]
        print("| " + " | ".join(cells) + " |")
