"""How instance preprocessing's time grows with the data: the stages of ``run_preprocessing`` (as
``ns-train idsplat`` runs it without model files: self-supervised, lidar-motion masks, DAISY
features) timed on cuts of one built-in street, its first F frames with every S-th lidar column,
with the tracking it buys beside each (MOTA@2m and MOTP@2m of the moving vehicles on the cut, and
their mean box-corner error), for this checkout's engine and, with ``--against REV``, another
revision's in the same run (ratios: the machine is noisy).

    .venv/bin/python -m bench.bench_preprocessing_scale --preset tiny --sizes 10x1 --seeds 3
    .venv/bin/python -m bench.bench_preprocessing_scale --preset segment --seeds 100 \\
        --sizes 50x1 100x1 200x1 200x2 200x4 --against HEAD --threads 2 --work WORK --out TABLE.md

``segment`` is a real segment's size (Waymo's: 200 frames, five cameras, 64 beams x 2,650
columns). A size ``FxS`` is the first F frames, each sweep keeping the rays of every S-th column
of the preset's ``azimuth_steps`` (so points a sweep fall as 1/S, the scene and its movers the
same). Every frame of a cut is preprocessed (no held-out split): the time for F frames of data.
Each run is a child process on a fresh cache (``revisions.run_child``) with ``--threads`` threads;
seconds are those of each stage computed from nothing, loading the street not counted.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

from idsplat_ns._compat.libusb import import_open3d
from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.synthetic import generate_sequence, get_preset
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.runner import PreprocessConfig

from bench.revisions import run_child, trees
from bench.tracking_quality import evaluate

CONFIG = PreprocessConfig(masks=MaskConfig(kind="lidar-motion"))
STAGES = ("mask generation", "features", "registration", "smoothing")  # the table's stage columns; the rest is "other"


def parse_size(text: str) -> tuple[int, int]:
    """``FxS`` -> (frames, column step)."""
    frames, sep, step = text.partition("x")
    try:
        out = int(frames), int(step or 1)
    except ValueError:
        raise SystemExit(f"--sizes {text!r}: write FRAMESxSTEP, e.g. 200x2") from None
    if out[0] < 2 or out[1] < 1:
        raise SystemExit(f"--sizes {text!r}: at least 2 frames and a column step of 1 or more")
    return out


def every_nth_column(sweep: LidarSweep, columns: int, step: int) -> LidarSweep:
    """The sweep's rays of every ``step``-th of ``columns`` azimuth columns (the sensor's frame)."""
    if step == 1:
        return sweep
    local = sweep.directions @ sweep.sensor_to_world[:3, :3]  # world -> sensor: R^T d
    azimuth = np.arctan2(local[:, 1], local[:, 0]) + np.pi  # [N] in [0, 2 pi]
    column = np.minimum((azimuth / (2 * np.pi) * columns).astype(np.int64), columns - 1)
    return sweep.select(column % step == 0)


def cut(scene: Scene, frames: int, columns: int, step: int) -> Scene:
    """The first ``frames`` frames of ``scene``, every ``step``-th lidar column kept."""
    first = scene.subset(set(scene.frame_indices[:frames].tolist()))
    return replace(first, lidar=[every_nth_column(s, columns, step) for s in first.lidar])


def child(args: argparse.Namespace) -> None:
    """One preprocessing of one cut on a fresh cache; prints ``RESULT <json>``."""
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    import_open3d()  # before the timing (about 1.5 s)
    scene = cut(load_sequence(args.street), args.frames, args.columns, args.step)
    points = float(np.mean([s.returned.sum() for s in scene.lidar]))
    with tempfile.TemporaryDirectory(prefix="idsplat_scale_") as cache:
        r = evaluate(scene, set(scene.frame_indices.tolist()), CONFIG, Path(cache))
    print("RESULT " + json.dumps({"frames": scene.num_frames, "images": len(scene.images), "points": points,
                                  **{k: r[k] for k in ("mota", "motp", "corner", "dynamic", "static", "seconds", "stages")}}))


def _row(name: str, size: str, r: dict) -> str:
    stages = {s[0]: s[1] for s in r["stages"]}
    cells = [f"{stages.get(s, 0.0):.1f}" for s in STAGES]
    other = r["seconds"] - sum(stages.get(s, 0.0) for s in STAGES)
    return (f"| {name} | {size} | {r['frames']} | {r['points'] / 1e3:.0f}k | {r['dynamic']} | " + " | ".join(cells)
            + f" | {other:.1f} | **{r['seconds']:.1f}** | {r['mota']:.3f} | {r['motp']:.3f} | {r['corner']:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="segment")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100])
    ap.add_argument("--sizes", nargs="+", default=["50x1", "100x1", "200x1", "200x2", "200x4"],
                    help="cuts FRAMESxSTEP: the first FRAMES frames, every STEP-th lidar column")
    ap.add_argument("--against", default=None, help="also time this git revision's engine")
    ap.add_argument("--against-tree", type=Path, default=None, help="also time the engine of this source tree")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--work", type=Path, default=None, help="folder for the streets (default: temporary)")
    ap.add_argument("--out", type=Path, default=None, help="also write the table to this file")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--street", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--frames", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--step", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--columns", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args)
    sizes = [(s, *parse_size(s)) for s in args.sizes]
    engines = trees("bench_preprocessing_scale", args.against, args.against_tree)
    columns = get_preset(args.preset).lidar.azimuth_steps
    work = args.work or Path(tempfile.mkdtemp(prefix="idsplat_scale_"))
    lines = ["| engine | size | frames | points a sweep | instances | masks s | features s | registration s "
             "| smoothing s | other s | total s | MOTA@2m | MOTP@2m m | corner m |", "|---" * 14 + "|"]
    totals: dict[tuple[int, str], dict[str, float]] = {}
    for seed in args.seeds:
        street = generate_sequence(work / "seq", preset=args.preset, seed=seed, overwrite=False)
        for label, frames, step in sizes:
            for name, tree in engines.items():
                cmd = ["-m", "bench.bench_preprocessing_scale", "--child", "--street", str(street), "--frames", str(frames),
                       "--step", str(step), "--columns", str(columns), "--threads", str(args.threads)]
                r = run_child("bench_preprocessing_scale", cmd, tree, args.threads)
                totals.setdefault((seed, label), {})[name] = r["seconds"]
                lines.append(_row(name, f"{args.preset} {seed} {label}", r))
                print(lines[-1], flush=True)
    notes = [f"seconds of each stage computed from nothing, {args.threads} thread(s); other: point painting, static "
             "conversion, amodal centres; MOTA@2m, MOTP@2m and corner error of the moving vehicles on the cut"]
    if len(engines) > 1:
        new, old = list(engines)[:2]
        ratios = [f"{seed} {label}: {t[new] / t[old]:.2f}" for (seed, label), t in totals.items()]
        notes.append(f"total time of {new} / {old}: " + ", ".join(ratios))
    table = "\n".join(lines + [""] + notes)
    print("\n" + table, flush=True)
    if args.out is not None:
        args.out.write_text(table + "\n")


if __name__ == "__main__":
    main()
