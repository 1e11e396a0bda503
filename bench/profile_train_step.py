"""Where a training step's time goes: ``ns-train``'s own trainer (method preset, data manager,
model, callbacks) on a built-in street, timed over whole steps and profiled with cProfile.

On a GPU run it twice: plainly for the step time, and with ``CUDA_LAUNCH_BLOCKING=1`` for the
profile, where every kernel's time is charged to the Python call that launched it (without it,
the time lands on whichever call waits for the GPU first).

    .venv/bin/python bench/profile_train_step.py --method idsplat-fast --preset small --out /tmp/prof
    CUDA_LAUNCH_BLOCKING=1 python bench/profile_train_step.py --method idsplat --seed 100 --out OUT
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


def build_trainer(method: str, preset: str, seed: int, mode: str, out: Path):
    """The trainer ``ns-train METHOD idsplat-builtin --preset P --seed S`` would run, set up."""
    from nerfstudio.scripts.train import _set_random_seed

    import method_configs.idsplat as methods
    from idsplat_ns.nerfstudio.builtin_scene import builtin_street

    cfg = getattr(methods, PRESETS[method]).config
    cfg.pipeline.datamanager.dataparser.data = builtin_street(preset, seed)
    cfg.pipeline.datamanager.instance_mode = mode
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", default="idsplat-fast", choices=list(PRESETS))
    ap.add_argument("--preset", default="small")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mode", default="oracle", help="instance mode (oracle needs no preprocessing)")
    ap.add_argument("--start-step", type=int, default=100, help="step number of the first step (schedules)")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--camera-backend", default="auto", choices=["auto", "torch"],
                    help="torch: the tile rasterizer even where gsplat is installed (no CUDA build needed)")
    ap.add_argument("--top", type=int, default=45, help="rows of the profile, by cumulative time")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.camera_backend == "torch":
        import idsplat_ns.render.camera as camera

        camera._gsplat_available = lambda: False  # "auto" then picks the tile rasterizer

    trainer = build_trainer(args.method, args.preset, args.seed, args.mode, args.out)
    model = trainer.pipeline.model
    run_steps(trainer, args.start_step, args.warmup)
    timed = run_steps(trainer, args.start_step + args.warmup, args.steps)
    prof = cProfile.Profile()
    prof.enable()
    run_steps(trainer, args.start_step + args.warmup + args.steps, args.steps)
    prof.disable()
    text = io.StringIO()
    pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(args.top)
    result = {
        "method": args.method, "street": f"{args.preset} {args.seed}", "mode": args.mode,
        "device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
        "camera_backend": args.camera_backend, "gaussians": int(model.gaussians.num), "steps": timed,
        "median_step_s": statistics.median(timed),
    }
    (args.out / "profile.txt").write_text(text.getvalue())
    (args.out / "step_times.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result))
    print("\n".join(text.getvalue().splitlines()[: args.top + 12]))


if __name__ == "__main__":
    main()
