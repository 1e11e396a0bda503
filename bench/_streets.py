"""The synthetic streets the tracking benches run on: the same options and the same training
frames (the dataparser's split) in ``bench_tracking.py`` and ``bench_smoothed_poses.py``."""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Iterator
from pathlib import Path

from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.split import split_frames
from idsplat_ns.data.synthetic import generate_sequence


def street_arguments(description: str) -> argparse.ArgumentParser:
    """``--preset``, ``--seeds``, ``--train-fraction`` and ``--work``."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--preset", default="small")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--train-fraction", type=float, default=0.5)
    ap.add_argument("--work", type=Path, default=None, help="folder for sequences and caches (default: temporary)")
    return ap


def training_streets(args: argparse.Namespace, prefix: str) -> Iterator[tuple[int, Scene, set[int], Path]]:
    """Per seed: the street (generated into ``work/seq`` if missing), its training frame indices
    and its instance cache folder (``work/cache-<seed>``)."""
    work = args.work or Path(tempfile.mkdtemp(prefix=prefix))
    for seed in args.seeds:
        scene = load_sequence(Path(generate_sequence(work / "seq", preset=args.preset, seed=seed, overwrite=False)))
        train_idx, _ = split_frames(scene.num_frames, args.train_fraction, None)
        yield seed, scene, set(scene.frame_indices[train_idx].tolist()), work / f"cache-{seed}"
