"""The built-in synthetic street: made on first use, cached, reused afterwards."""

from __future__ import annotations

import os
from pathlib import Path

from idsplat_ns.data.synthetic import generate_sequence, get_preset, is_current, sequence_name


def cache_root() -> Path:
    """Where generated scenes are kept: ``$IDSPLAT_CACHE`` or ``~/.cache/idsplat_ns``."""
    return Path(os.environ.get("IDSPLAT_CACHE", Path.home() / ".cache" / "idsplat_ns")).expanduser()


def instance_cache_dir(scene_name: str) -> Path:
    """Where a sequence's instance preprocessing stages are cached: ``ns-train`` and
    ``idsplat-preprocess`` share it, each stage keyed by its inputs and settings."""
    return cache_root() / "instances" / scene_name


def builtin_street(preset: str = "small", seed: int = 0) -> Path:
    """Path to the built-in street of ``preset``/``seed``, generating it the first time."""
    parent = cache_root() / "synthetic"
    if is_current(parent, preset, seed):
        return parent / sequence_name(get_preset(preset), seed)
    parent.mkdir(parents=True, exist_ok=True)
    # Missing, or made by another generator version: this cache is the project's own, so it is
    # (re)written, to a temporary folder first and then renamed.
    return Path(generate_sequence(parent, preset=preset, seed=seed, overwrite=True))
