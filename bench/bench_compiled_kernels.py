"""Time the compiled camera compositor's kernels alone: forward and backward of
``CompiledGaussianComposite`` on the inputs that one camera render gives it (garden points as in
``bench_rasterizer.py``), without the projection, tile sorting and torch ops around them.

    .venv/bin/python -m bench.bench_compiled_kernels --threads 1
    .venv/bin/python -m bench.bench_compiled_kernels --module /tmp/variant.py --threads 1

``--module`` times another copy of ``idsplat_ns/render/compiled_composite.py`` (a variant being
tried) on the same inputs; the first call of a fresh copy compiles it (untimed warm-up).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path

import torch

import idsplat_ns.render as render
import idsplat_ns.render.compiled_composite as compiled
from bench.bench_rasterizer import make_scene



def kernel_inputs(n: int, width: int, height: int) -> dict:
    """The arguments of ``CompiledGaussianComposite.apply`` in one camera render."""
    scene = make_scene(n, width, height)
    seen = {}
    original = compiled.CompiledGaussianComposite.apply

    def capture(params, feats, plan, centres):
        seen.update(params=params.detach(), feats=feats.detach(), plan=plan, centres=centres)
        return original(params, feats, plan, centres)

    compiled.CompiledGaussianComposite.apply = capture
    try:
        with torch.no_grad():
            render.rasterize_camera(**scene, width=width, height=height, backend="torch", compositor="compiled")
    finally:
        compiled.CompiledGaussianComposite.apply = original
    return seen


def load_variant(path: Path):
    spec = importlib.util.spec_from_file_location("idsplat_ns.render._kernel_variant", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--count", type=int, default=100_000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--module", type=Path, default=None, help="a copy of compiled_composite.py to time instead")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    width, height = (int(v) for v in args.size.split("x"))
    inputs = kernel_inputs(args.count, width, height)
    function = (load_variant(args.module) if args.module else compiled).CompiledGaussianComposite
    forward, backward = [], []
    for i in range(args.repeats + 1):
        params = inputs["params"].clone().requires_grad_()
        feats = inputs["feats"].clone().requires_grad_()
        t0 = time.perf_counter()
        pix, _ = function.apply(params, feats, inputs["plan"], inputs["centres"])
        t1 = time.perf_counter()
        pix.backward(torch.ones_like(pix))
        t2 = time.perf_counter()
        if i:  # the first call may compile
            forward.append(t1 - t0)
            backward.append(t2 - t1)
    rows = inputs["plan"].gaussian_ids.numel()
    print(f"{args.size}, {args.count:,} Gaussians, {rows:,} intersections, {args.threads} thread(s), "
          f"medians of {args.repeats}: forward {statistics.median(forward):.4f} s, "
          f"backward {statistics.median(backward):.4f} s")  # fmt: skip


if __name__ == "__main__":
    main()
