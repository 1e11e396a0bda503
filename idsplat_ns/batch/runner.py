"""The batch's driver: starts (or joins) Ray, submits each sequence's steps as Ray tasks with their
declared resources, chains a sequence's next step when its previous one ends, and reports every
state change. Ray places the tasks: with preprocessing and training separate, one sequence's
CPU-bound preprocessing runs beside another's training.
"""

from __future__ import annotations

import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Optional

import ray
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from idsplat_ns.batch.layout import read_status, write_status
from idsplat_ns.batch.plan import SequencePlan, Step, finish_eval
from idsplat_ns.batch.ray_cluster import RayStart, start_ray
from idsplat_ns.batch.tasks import run_step
from idsplat_ns.errors import IDSplatError

if TYPE_CHECKING:
    from rich.console import Console


@dataclass(frozen=True)
class StepResources:
    """What one task of a step asks Ray for."""

    num_cpus: float = 1.0
    """CPU cores (Ray also sets OMP_NUM_THREADS to this for the task, so torch uses as many threads)."""
    num_gpus: Optional[float] = None
    """GPUs; None: 1 where the Ray cluster has GPUs, else 0."""
    memory_gb: float = 0.0
    """Memory reserved for the task in GiB (0: none declared; Ray then places by CPUs and GPUs only)."""

    def ray_options(self, cluster_has_gpu: bool) -> dict:
        gpus = (1.0 if cluster_has_gpu else 0.0) if self.num_gpus is None else self.num_gpus
        opts: dict = {"num_cpus": self.num_cpus, "num_gpus": gpus}
        if self.memory_gb > 0:
            opts["memory"] = int(self.memory_gb * 2**30)
        return opts


@dataclass
class Outcome:
    """How each sequence of a batch ended."""

    done: list[str] = field(default_factory=list)
    """Evaluated by this run."""
    skipped: list[str] = field(default_factory=list)
    """Already evaluated before."""
    failed: dict[str, str] = field(default_factory=dict)
    """Sequence -> ``<step>: <one-line error>``."""


def check_feasible(resources: dict[str, dict]) -> None:
    """One-line error when no Ray node can run a step's task (Ray would wait for it forever)."""
    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    names = {"num_cpus": "CPU", "num_gpus": "GPU", "memory": "memory"}
    for step, opts in resources.items():
        if any(all(node.get(names[k], 0.0) >= v for k, v in opts.items() if v) for node in nodes):
            continue
        asked = ", ".join(f"{names[k]} {v / 2**30:.1f} GiB" if k == "memory" else f"{names[k]} {v:g}"
                          for k, v in opts.items() if v)
        largest = ", ".join(f"{k} {v:g}" for k, v in sorted(nodes[0].items()) if k in ("CPU", "GPU")) if nodes else "none"
        raise IDSplatError(f"--{step}-cpus/--{step}-gpus/--{step}-memory-gb: no Ray node has {asked} "
                           f"(a node has {largest}); ask for less")


class Reporter:
    """State lines (console and OUTPUT_DIR/batch.log) and the overall progress bar."""

    def __init__(self, log_path: Path, print_fn: Callable[[str], None]):
        self.log_path = log_path
        self.start = time.perf_counter()
        self.print_fn = print_fn
        # The bar's step counter; the driver replaces it when it shows a bar.
        self.advance: Callable[[], None] = lambda: None

    def line(self, sequence: str, text: str) -> None:
        msg = f"[{time.perf_counter() - self.start:7.1f} s] {sequence}: {text}"
        self.print_fn(msg)
        with open(self.log_path, "a") as f:
            f.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {msg}\n")


def _submit(step: Step, plan: SequencePlan, options: dict, env: dict[str, str]):
    return run_step.options(**options, name=f"{step.kind}:{plan.sequence.name}").remote(
        list(step.argv), str(plan.paths.log(step.kind)), env)


def _describe_done(results: Optional[dict]) -> str:
    if not results:
        return "done (eval.json unreadable)"
    parts = [f"{k.upper()} {results[k]:.2f}" for k in ("psnr", "dpsnr") if isinstance(results.get(k), (int, float))]
    return "done" + (f": {', '.join(parts)}" if parts else "")


def run_plans(plans: list[SequencePlan], step_resources: dict[str, StepResources], reporter: Reporter,
              env: dict[str, str]) -> Outcome:
    """Run every plan's steps on the (started) Ray cluster; failures are recorded, not raised."""
    has_gpu = ray.cluster_resources().get("GPU", 0.0) >= 1.0
    options = {kind: res.ray_options(has_gpu) for kind, res in step_resources.items()}
    check_feasible(options)
    outcome = Outcome()
    queue: dict[str, list[Step]] = {}
    inflight: dict = {}  # ObjectRef -> (plan, step)

    def start_next(plan: SequencePlan) -> None:
        steps = queue[plan.sequence.name]
        if not steps:
            return
        step = steps.pop(0)
        write_status(plan.paths, {"state": step.kind, "note": step.note, "data": str(plan.sequence.data),
                                  "protocol": plan.sequence.protocol})
        reporter.line(plan.sequence.name, {"preprocess": "preprocessing", "train": "training", "eval": "evaluating"}[step.kind]
                      + (f" ({step.note})" if step.note else ""))
        inflight[_submit(step, plan, options[step.kind], env)] = (plan, step)

    for plan in plans:
        if not plan.steps:
            outcome.skipped.append(plan.sequence.name)
            reporter.line(plan.sequence.name, "skipped, already evaluated (eval.json)")
            continue
        queue[plan.sequence.name] = list(plan.steps)
        start_next(plan)

    try:
        while inflight:
            ready, _ = ray.wait(list(inflight), num_returns=1)
            plan, step = inflight.pop(ready[0])
            name = plan.sequence.name
            try:
                result = ray.get(ready[0])
                code, error, seconds = result.returncode, result.error, result.seconds
            except ray.exceptions.RayError as err:  # the worker itself died (killed, node lost)
                code, error, seconds = -1, " ".join(str(err).split())[:400], 0.0
            reporter.advance()
            if code != 0:
                outcome.failed[name] = f"{step.kind}: {error}"
                reporter.line(name, f"FAILED at {step.kind} after {seconds:.0f} s: {error} (log: {plan.paths.log(step.kind)})")
                write_status(plan.paths, {"state": "failed", "step": step.kind, "error": error, "returncode": code,
                                          "data": str(plan.sequence.data), "protocol": plan.sequence.protocol})
                for _ in queue[name]:
                    reporter.advance()  # the bar counts the steps that will not run as settled
                queue[name] = []
                continue
            if step.kind == "eval":
                results = finish_eval(plan.paths)
                outcome.done.append(name)
                write_status(plan.paths, {"state": "done", "data": str(plan.sequence.data), "protocol": plan.sequence.protocol})
                reporter.line(name, f"{_describe_done(results)} ({seconds:.0f} s)")
                continue
            reporter.line(name, f"{step.kind} finished in {seconds:.0f} s")
            start_next(plan)
    except KeyboardInterrupt:
        for plan, step in inflight.values():
            status = read_status(plan.paths)
            status.update(state="interrupted", step=step.kind)
            write_status(plan.paths, status)
            reporter.line(plan.sequence.name, f"interrupted during {step.kind} (a re-run continues it)")
        raise
    return outcome


def raise_keyboard_interrupt(signum, frame) -> None:
    """SIGTERM handler: end like Ctrl-C, so that the driver's cleanup (ray.shutdown) runs."""
    raise KeyboardInterrupt(f"signal {signum}")


def install_sigterm() -> None:
    signal.signal(signal.SIGTERM, raise_keyboard_interrupt)


def run_on_ray(plans: list[SequencePlan], ray_start: RayStart, resources: dict[str, StepResources],
               env: dict[str, str], console: Console, log_path: Path, n_steps: int) -> Outcome:
    """Start or join Ray, run the plans under a progress bar; Ray is shut down whatever happens."""
    try:
        start_ray(ray_start)
        install_sigterm()  # after ray.init, which installs a SIGTERM handler of its own that skips our cleanup
        with Progress(TextColumn("batch"), BarColumn(), MofNCompleteColumn(), TextColumn("steps"), TimeElapsedColumn(),
                      console=console, transient=False) as progress:
            bar = progress.add_task("steps", total=max(n_steps, 1))
            reporter = Reporter(log_path, lambda msg: progress.console.print(msg, markup=False, highlight=False))
            reporter.advance = lambda: progress.advance(bar)
            return run_plans(plans, resources, reporter, env)
    finally:
        ray.shutdown()  # also on Ctrl-C/SIGTERM: workers, and with them the steps' subprocesses, end
