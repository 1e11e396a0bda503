"""Operators a training step runs, counted on any device: each one costs a launch from Python on
a GPU, so their number bounds a step whose GPU is faster than its host. Also the operators that
make the host wait for a CUDA device (scalar reads, ``nonzero``, ``unique``, boolean-mask
indexing...), by source line. A dispatch hook sees every operator, the backward pass's too. On
the CPU every tensor is a host tensor, so reads of what stays on the host on CUDA too (the lidar
batch's CPU copies of its ray times, Adam's step counters) are counted as well.

    .venv/bin/python -m bench.count_step_operators --method idsplat --preset tiny --seed 100 \\
        --variant tile-torch:torch --out /tmp/ops [--model-set exposure=True camera_refinement=True]
"""

from __future__ import annotations

import argparse
import ast
import collections
import json
import threading
import traceback
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

from bench.profile_train_step import PRESETS, build_trainer, run_steps, set_variant

# Operators whose CUDA implementation returns a size or a value to the host before it returns.
_HOST_READS = {"_local_scalar_dense", "nonzero", "_unique2", "unique_dim", "unique_consecutive", "masked_select",
               "repeat_interleave", "bincount", "nonzero_static"}
# Indexing is a host read only with a boolean mask.
_MASKABLE = {"index", "index_put", "index_put_", "_index_put_impl_"}
_OURS = ("/idsplat_ns/", "/nerfstudio/", "/torch/optim/")


def _site(stack: list[traceback.FrameSummary]) -> str:
    frames = [f for f in stack if any(part in f.filename for part in _OURS)]
    if not frames:
        return "(outside the project)"
    f = frames[-1]
    name = f.filename.split("site-packages/")[-1]
    for root in ("idsplat_ns/", "nerfstudio/", "torch/"):
        if root in name:
            name = name[name.index(root):]
            break
    return f"{name}:{f.lineno}"


class OperatorCensus(TorchDispatchMode):
    """Counts the operators dispatched while it is active, by source file, and the host reads by line."""

    def __init__(self) -> None:
        super().__init__()
        self.by_file: collections.Counter = collections.Counter()
        self.by_line: collections.Counter = collections.Counter()
        self.host_reads: collections.Counter = collections.Counter()
        self.backward = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.__name__.split(".")[0]
        stack = traceback.extract_stack()
        site = _site(stack)
        self.by_file[site.rsplit(":", 1)[0]] += 1
        self.by_line[site] += 1
        if threading.current_thread() is not threading.main_thread() or any("backward" in (f.line or "") for f in stack[-8:]):
            self.backward += 1
        masked = name in _MASKABLE and any(isinstance(i, torch.Tensor) and i.dtype == torch.bool
                                           for i in (args[1] if len(args) > 1 else []) if i is not None)  # fmt: skip
        if name in _HOST_READS or masked:
            self.host_reads[f"{site} {name}{'[bool]' if masked else ''}"] += 1
        return func(*args, **(kwargs or {}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", default="idsplat", choices=list(PRESETS))
    ap.add_argument("--preset", default="tiny")
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--mode", default="oracle", help="instance mode (oracle needs no preprocessing)")
    ap.add_argument("--variant", default="tile-torch:torch", metavar="CAMERA:LIDAR",
                    help="camera rasterizer and lidar compositor, as bench.profile_train_step --variants")
    ap.add_argument("--start-step", type=int, default=100)
    ap.add_argument("--top", type=int, default=20, help="files listed")
    ap.add_argument("--lines", type=int, default=0, help="source lines listed, most operators first")
    ap.add_argument("--model-set", nargs="*", default=[], metavar="NAME=VALUE",
                    help="model settings changed (exposure=True camera_refinement=True; VALUE a Python literal)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    settings = {}
    for item in args.model_set:
        name, sep, text = item.partition("=")
        if not sep:
            raise SystemExit(f"--model-set {item!r}: write NAME=VALUE")
        settings[name] = ast.literal_eval(text)
    args.out.mkdir(parents=True, exist_ok=True)
    camera, _, lidar = args.variant.partition(":")
    trainer = build_trainer(args.method, args.preset, args.seed, args.mode, args.out, settings)
    set_variant(trainer, camera, lidar or "torch")
    run_steps(trainer, args.start_step, 2)  # warm-up: lazy buffers, first-step branches
    census = OperatorCensus()
    with census:
        run_steps(trainer, args.start_step + 2, 1)
    total = sum(census.by_file.values())
    result = {"method": args.method, "street": f"{args.preset} {args.seed}", "variant": args.variant,
              "operators": total, "backward_operators": census.backward,
              "host_reads": sum(census.host_reads.values()), "by_file": dict(census.by_file.most_common()),
              "by_line": dict(census.by_line.most_common()),
              "host_reads_by_line": dict(sorted(census.host_reads.items()))}  # fmt: skip
    (args.out / "operators.json").write_text(json.dumps(result, indent=1))
    print(f"operators a step: {total:,} ({census.backward:,} in the backward pass); "
          f"host reads on CUDA: {result['host_reads']}")
    for name, count in census.by_file.most_common(args.top):
        print(f"{count:7,d}  {name}")
    for name, count in census.by_line.most_common(args.lines):
        print(f"{count:7,d}  {name}")


if __name__ == "__main__":
    main()
