"""The synthetic streets the tracking benches run on: the same options and the same training
frames (the dataparser's split) in ``bench_tracking.py`` and ``bench_smoothed_poses.py``; and
preprocessing settings changed by their dotted names (``bench_rule_ablation.py``, ``--set``)."""

from __future__ import annotations

import argparse
import ast
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import replace
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


def config_names(path: str) -> list[str]:
    """The field names of a dotted setting in ``PreprocessConfig`` (``registration.*`` is named as
    the docs name it; it lives in the trajectory config)."""
    names = path.split(".")
    return ["trajectory", *names] if names[0] == "registration" else names


def setting_of(path: str, value) -> Callable:
    """A function of a config that returns it with the field at dotted ``path`` set to ``value``
    (nested frozen dataclasses)."""
    names = config_names(path)

    def apply(c, names=tuple(names)):
        if len(names) == 1:
            if not hasattr(c, names[0]):
                raise SystemExit(f"no setting {path!r} ({type(c).__name__} has no field {names[0]!r})")
            return replace(c, **{names[0]: value})
        return replace(c, **{names[0]: apply(getattr(c, names[0]), names[1:])})

    return apply


def parse_settings(items: list[str]) -> list[Callable]:
    """``PATH=VALUE`` items (``masks.lidar_motion.max_extent=14``; VALUE a Python literal, else a
    string) as :func:`setting_of` functions."""
    out = []
    for item in items:
        path, sep, text = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: write PATH=VALUE")
        try:
            value = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            value = text
        out.append(setting_of(path, value))
    return out
