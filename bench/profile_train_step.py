"""Where a training step's time goes: ``ns-train``'s own trainer (method preset, data manager,
model, callbacks) on a built-in street, timed over whole steps and profiled with cProfile.

On a GPU run it twice: plainly for the step time, and with ``CUDA_LAUNCH_BLOCKING=1`` for the
profile, where every kernel's time is charged to the Python call that launched it (without it,
the time lands on whichever call waits for the GPU first).

    .venv/bin/python -m bench.profile_train_step --method idsplat-fast --preset small --out /tmp/prof
    CUDA_LAUNCH_BLOCKING=1 python -m bench.profile_train_step --method idsplat --seed 100 --out OUT

``--variants`` times engines side by side instead of profiling: (camera backend, lidar compositor)
pairs take turns on one trainer, ``--rounds`` times, and a table of median step times, their
ratios to the first pair and the peak GPU memory is written (``step_times.md``)::

    python -m bench.profile_train_step --method idsplat --seed 100 --start-step 100 --warmup 3 --steps 25 \
        --rounds 3 --variants tile-torch:torch tile-triton:triton gsplat:triton --out OUT
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import statistics
import time
from pathlib import Path

import torch


# The registered presets: ns-train name -> MethodSpecification in method_configs/idsplat.py.
PRESETS = {"idsplat": "idsplat_method", "idsplat-fast": "idsplat_fast_method", "idsplat-preview": "idsplat_preview_method",
           "idsplat-medium": "idsplat_medium_method"}


def _sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def build_trainer(method: str, preset: str, seed: int, mode: str, out: Path, model_settings: dict | None = None):
    """The trainer ``ns-train METHOD idsplat-builtin --preset P --seed S`` would run, set up, with
    ``model_settings`` (``--pipeline.model.NAME VALUE``) changed."""
    from nerfstudio.scripts.train import _set_random_seed

    import method_configs.idsplat as methods
    from idsplat_ns.nerfstudio.builtin_scene import builtin_street

    cfg = getattr(methods, PRESETS[method]).config
    cfg.pipeline.datamanager.dataparser.data = builtin_street(preset, seed)
    cfg.pipeline.datamanager.instance_mode = mode
    for name, value in (model_settings or {}).items():
        if not hasattr(cfg.pipeline.model, name):
            raise SystemExit(f"--model-set {name}: the model config has no such setting")
        setattr(cfg.pipeline.model, name, value)
    cfg.vis = "tensorboard"
    cfg.output_dir = out / "run"
    cfg.experiment_name = "profile"
    cfg.set_timestamp()
    cfg.save_config()
    _set_random_seed(cfg.machine.seed)
    trainer = cfg.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer


def run_steps(trainer, first: int, count: int) -> list[float]:
    """Seconds of each of ``count`` steps from ``first``, callbacks included, as the trainer runs them."""
    from nerfstudio.engine.callbacks import TrainingCallbackLocation

    seconds = []
    for step in range(first, first + count):
        _sync()
        t0 = time.perf_counter()
        for cb in trainer.callbacks:
            cb.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        trainer.train_iteration(step)
        for cb in trainer.callbacks:
            cb.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)
        _sync()
        seconds.append(time.perf_counter() - t0)
    return seconds


def _peak_gib() -> float:
    return torch.cuda.max_memory_allocated() / 2**30 if torch.cuda.is_available() else float("nan")


def set_variant(trainer, camera: str, lidar_compositor: str) -> None:
    """Switch the engine of a built trainer: the camera rasterizer (``gsplat``, ``auto``, or the tile
    rasterizer with a named compositor, ``tile-torch``, ``tile-triton``, ``tile-compiled``) and the
    lidar compositor."""
    model = trainer.pipeline.model
    backend, _, comp = camera.partition("-")
    model.scene_model.camera_backend = "torch" if backend == "tile" else backend
    model.scene_model.camera_compositor = comp or "auto"
    if model.lidar is not None:
        model.lidar.config.compositor = lidar_compositor


def time_variants(trainer, variants: list[tuple[str, str]], start: int, warmup: int, steps: int, rounds: int,
                  progress=None) -> dict:  # fmt: skip
    """Each (camera rasterizer, lidar compositor) for ``warmup`` untimed and ``steps`` timed steps,
    in turn, ``rounds`` times, on one trainer (its steps go on: load and the Gaussian count fall on
    all alike). A variant that fails (gsplat not built) is written down and left out of later
    rounds. ``progress(results)`` is called after each variant's turn (a killed run keeps its rows)."""
    results = {f"{c}:{l}": {"steps": [], "peak_gib": 0.0, "error": None} for c, l in variants}
    step = start
    for _ in range(rounds):
        for cam, lid in variants:
            res = results[f"{cam}:{lid}"]
            if res["error"]:
                continue
            set_variant(trainer, cam, lid)
            try:
                step += len(run_steps(trainer, step, warmup))
                if torch.cuda.is_available():
                    torch.cuda.reset_peak_memory_stats()
                timed = run_steps(trainer, step, steps)
            except Exception as exc:  # noqa: BLE001  (a bench row, not a program: record and go on)
                res["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                print(f"variant {cam}:{lid} failed: {res['error']}", flush=True)
                continue
            step += steps
            res["steps"] += timed
            res["peak_gib"] = max(res["peak_gib"], _peak_gib())
            res["median_step_s"] = statistics.median(res["steps"])
            if progress is not None:
                progress(results)
            print(f"variant {cam}:{lid}: median {statistics.median(timed):.4f} s over {steps} steps, "
                  f"Gaussians {int(trainer.pipeline.model.gaussians.num):,}", flush=True)  # fmt: skip
    for res in results.values():
        res.setdefault("median_step_s", None)
    return results


# Runtime calls that make the host wait for the GPU: each one inside a step stalls the launch queue.
_HOST_SYNCS = ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaMemcpyAsync", "cudaEventSynchronize")


def torch_profile(trainer, first: int, count: int, top: int) -> str:
    """``count`` steps under torch.profiler: the operators by device time, and the host
    synchronisations per step (CUDA runtime calls that wait for the GPU)."""
    from torch.profiler import ProfilerActivity, profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if torch.cuda.is_available() else [])
    with profile(activities=activities) as prof:
        run_steps(trainer, first, count)
    events = prof.key_averages()
    sort = "cuda_time_total" if torch.cuda.is_available() else "cpu_time_total"
    syncs = {e.key: e.count for e in events if e.key in _HOST_SYNCS}
    lines = ["host synchronisations per step: " + ", ".join(f"{k} {v / count:.1f}" for k, v in syncs.items())]
    return "\n".join(lines) + "\n" + events.table(sort_by=sort, row_limit=top)


def variants_table(results: dict, base: str) -> str:
    """Markdown rows: median step time, its ratio to ``base``'s, peak GPU memory."""
    lines = ["| camera rasterizer:lidar compositor | steps timed | median step s | against " + base + " | peak GPU GiB |",
             "|---|---|---|---|---|"]  # fmt: skip
    ref = results[base].get("median_step_s")
    for name, res in results.items():
        med = res.get("median_step_s")
        if med is None:
            lines.append(f"| {name} | 0 | failed: {res['error']} | | |")
            continue
        ratio = f"{med / ref:.2f}x" if ref else ""
        lines.append(f"| {name} | {len(res['steps'])} | {med:.4f} | {ratio} | {res['peak_gib']:.1f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", default="idsplat-fast", choices=list(PRESETS))
    ap.add_argument("--preset", default="small")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mode", default="oracle", help="instance mode (oracle needs no preprocessing)")
    ap.add_argument("--start-step", type=int, default=100, help="step number of the first step (schedules)")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--camera-backend", default="auto",
                    choices=["auto", "gsplat", "torch", "tile-torch", "tile-triton", "tile-compiled"],
                    help="tile-*: the tile rasterizer even where gsplat is installed (no CUDA build needed), "
                         "with that compositor")  # fmt: skip
    ap.add_argument("--lidar-compositor", default="auto", choices=["auto", "compiled", "torch", "triton"])
    ap.add_argument("--variants", nargs="+", default=None, metavar="CAMERA:LIDAR",
                    help="time these (camera, lidar compositor) pairs in turn on one trainer, e.g. "
                         "tile-torch:torch gsplat:triton; the first is the base of the ratios; no profile")  # fmt: skip
    ap.add_argument("--rounds", type=int, default=2, help="with --variants: turns through all of them")
    ap.add_argument("--torch-profile", type=int, default=0, metavar="STEPS",
                    help="with --variants: then this many steps of the last pair under torch.profiler "
                         "(torch_profile.txt: operators by device time, host synchronisations per step)")  # fmt: skip
    ap.add_argument("--top", type=int, default=45, help="rows of the profile, by cumulative time")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    trainer = build_trainer(args.method, args.preset, args.seed, args.mode, args.out)
    model = trainer.pipeline.model
    info = {"method": args.method, "street": f"{args.preset} {args.seed}", "mode": args.mode,
            "device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
            "torch": torch.__version__, "gaussians_at_start": int(model.gaussians.num)}  # fmt: skip
    if args.variants:
        pairs = [tuple(v.split(":")) for v in args.variants]
        if any(len(p) != 2 for p in pairs):
            raise SystemExit("profile_train_step.py: --variants takes CAMERA:LIDAR pairs, e.g. tile-torch:torch gsplat:triton")
        def write(results: dict) -> str:
            table = variants_table(results, args.variants[0])
            result = dict(info, variants=results, gaussians_now=int(model.gaussians.num))
            (args.out / "step_times.json").write_text(json.dumps(result, indent=1))
            (args.out / "step_times.md").write_text(table + "\n")
            return table

        results = time_variants(trainer, pairs, args.start_step, args.warmup, args.steps, args.rounds, write)
        print(write(results))
        if args.torch_profile:
            cam, lid = pairs[-1]
            set_variant(trainer, cam, lid)
            step = args.start_step + args.rounds * len(pairs) * (args.warmup + args.steps)
            text = torch_profile(trainer, step, args.torch_profile, args.top)
            (args.out / "torch_profile.txt").write_text(f"variant {cam}:{lid}, {args.torch_profile} steps\n" + text)
            print(text)
        return
    set_variant(trainer, args.camera_backend, args.lidar_compositor)
    run_steps(trainer, args.start_step, args.warmup)
    timed = run_steps(trainer, args.start_step + args.warmup, args.steps)
    prof = cProfile.Profile()
    prof.enable()
    run_steps(trainer, args.start_step + args.warmup + args.steps, args.steps)
    prof.disable()
    text = io.StringIO()
    pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(args.top)
    result = dict(info, camera_backend=args.camera_backend, lidar_compositor=args.lidar_compositor,
                  gaussians=int(model.gaussians.num), steps=timed, median_step_s=statistics.median(timed))  # fmt: skip
    (args.out / "profile.txt").write_text(text.getvalue())
    (args.out / "step_times.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result))
    print("\n".join(text.getvalue().splitlines()[: args.top + 12]))


if __name__ == "__main__":
    main()
