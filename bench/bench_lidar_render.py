"""Time one training lidar batch (render, losses, backward) of a method preset on a built-in
street, side by side with another revision's engine in the same run.

The model is the one ``ns-train METHOD idsplat-builtin`` builds (oracle instance tracks, the
Gaussians as initialised); the batches are the lidar supervisor's own draws, the same sequence for
both revisions (same seed). Each revision runs in a child process of its own with ``PYTHONPATH``
on its source tree (a git worktree for ``--against``), the two alternating ``--rounds`` times, so
that load on the machine falls on both alike. Quote the medians and their ratio.

    .venv/bin/python -m bench.bench_lidar_render --against HEAD~1 --threads 1
    .venv/bin/python -m bench.bench_lidar_render --method idsplat --seed 100 --against v0 --out T.md

``--compositors torch triton`` times lidar compositors of one engine beside each other instead
(one model, the compositors alternating batch round by batch round), e.g. on a GPU machine::

    python -m bench.bench_lidar_render --method idsplat --seed 100 --compositors torch triton --rounds 2

Without git history (a GPU machine), pass the other revision as a source tree made here:
``git archive REV idsplat_ns | tar -x -C .prev`` and ``--against-tree .prev``. The other revision's
engine (``idsplat_ns``) runs with this checkout's presets either way.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from bench import revisions
from bench.profile_train_step import PRESETS, build_trainer


def _sync() -> None:
    import torch

    if torch.cuda.is_available():
        torch.cuda.synchronize()


def child(args: argparse.Namespace) -> None:
    """Build the model, then time ``--batches`` lidar batches after ``--warmup`` untimed ones, for
    each lidar compositor in turn, ``--inner-rounds`` times (one model: its setup is paid once)."""
    import torch

    torch.set_num_threads(args.threads)
    trainer = build_trainer(args.method, args.preset, args.seed, "oracle", Path(args.work))
    model = trainer.pipeline.model
    if model.lidar is None:
        raise SystemExit(f"bench_lidar_render.py: street {args.preset} {args.seed} has no lidar")
    times = {c: {"forward": [], "both": []} for c in args.compositors}
    rays = None
    for _ in range(args.inner_rounds):
        for comp in args.compositors:
            model.lidar.config.compositor = comp
            for i in range(args.warmup + args.batches):
                rays, pose = model.lidar.sample(model.device)
                _sync()
                t0 = time.perf_counter()
                out = model.lidar.render_batch(model.scene_model, rays, pose)
                loss = sum(model.lidar.losses(out).values())
                _sync()
                t1 = time.perf_counter()
                loss.backward()
                _sync()
                t2 = time.perf_counter()
                model.zero_grad(set_to_none=True)
                if i >= args.warmup:
                    times[comp]["forward"].append(t1 - t0)
                    times[comp]["both"].append(t2 - t0)
    print("RESULT " + json.dumps({"times": times, "rays": rays.num_rays, "gaussians": int(model.gaussians.num)}))


def run_child(tree: Path, args: argparse.Namespace, work: Path, inner_rounds: int) -> dict:
    cmd = ["-m", "bench.bench_lidar_render", "--child", "--method", args.method, "--preset", args.preset, "--seed", str(args.seed),
           "--threads", str(args.threads), "--warmup", str(args.warmup), "--batches", str(args.batches),
           "--work", str(work), "--inner-rounds", str(inner_rounds), "--compositors", *args.compositors]  # fmt: skip
    return revisions.run_child("bench_lidar_render.py", cmd, tree, args.threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--method", default="idsplat-fast", choices=list(PRESETS))
    ap.add_argument("--preset", default="small", help="built-in street preset")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    ap.add_argument("--warmup", type=int, default=2, help="untimed batches first")
    ap.add_argument("--batches", type=int, default=8, help="timed batches per round")
    ap.add_argument("--rounds", type=int, default=2, help="alternations of the revisions")
    ap.add_argument("--against", default=None, help="git revision to time beside the working tree")
    ap.add_argument("--against-tree", type=Path, default=None,
                    help="a source tree with idsplat_ns/ (e.g. from `git archive`) whose engine to time beside "
                         "the working tree's, where there is no git history (a GPU machine)")
    ap.add_argument("--compositors", nargs="+", default=["auto"], choices=["auto", "compiled", "torch", "triton"],
                    help="lidar compositors to time in turn, each a row (one model per revision)")
    ap.add_argument("--inner-rounds", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--work", type=Path, default=Path("/tmp/idsplat-bench-lidar"))
    ap.add_argument("--out", type=Path, default=None, help="also write the markdown table here")
    args = ap.parse_args()
    if args.child:
        child(args)
        return
    trees = revisions.trees("bench_lidar_render.py", args.against, args.against_tree)
    # One revision: its compositors alternate inside one child (the model is built once); several:
    # the revisions alternate, a child each round.
    outer, inner = (1, args.rounds) if len(trees) == 1 else (args.rounds, 1)
    times: dict[str, dict[str, list[float]]] = {}
    info = {}
    for r in range(outer):
        for name, tree in trees.items():
            res = run_child(tree, args, args.work / name.replace(" ", "_").replace("/", "_") / str(r), inner)
            info = res
            for comp, t in res["times"].items():
                row = name if len(args.compositors) == 1 else f"{name}, {comp} compositor"
                times.setdefault(row, {"forward": [], "both": []})
                times[row]["forward"] += t["forward"]
                times[row]["both"] += t["both"]
                print(f"round {r + 1}: {row}: forward {statistics.median(t['forward']):.3f} s, "
                      f"forward+backward {statistics.median(t['both']):.3f} s", flush=True)  # fmt: skip
    first = next(iter(times))
    base = statistics.median(times[first]["both"])
    lines = [f"{args.method}, street {args.preset} {args.seed}, {info['gaussians']:,} Gaussians, {info['rays']:,} rays "
             f"a batch, {args.threads} thread(s), medians of {args.rounds} x {args.batches} batches", "",
             f"| engine | forward s | forward+backward s | time against {first} |", "|---|---|---|---|"]  # fmt: skip
    for name, t in times.items():
        both = statistics.median(t["both"])
        lines.append(f"| {name} | {statistics.median(t['forward']):.3f} | {both:.3f} | {both / base:.2f}x |")
    text = "\n".join(lines)
    print("\n" + text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
