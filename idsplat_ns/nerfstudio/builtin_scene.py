"""The built-in synthetic street: made on first use, cached, reused afterwards."""

from __future__ import annotations

import os
from pathlib import Path

from idsplat_ns.errors import IDSplatError


def cache_root() -> Path:
    """Where generated scenes are kept: ``$IDSPLAT_CACHE`` or ``~/.cache/idsplat_ns``."""
    return Path(os.environ.get("IDSPLAT_CACHE", Path.home() / ".cache" / "idsplat_ns")).expanduser()


def builtin_street(preset: str = "small", seed: int = 0) -> Path:
    """Path to the built-in street of ``preset``/``seed``, generating it the first time."""
    from idsplat_ns.data.synthetic import generate_sequence

    parent = cache_root() / "synthetic"
    parent.mkdir(parents=True, exist_ok=True)
    try:
        # Returns the cached folder when its generator record (version, settings, seed) matches.
        return Path(generate_sequence(parent, preset=preset, seed=seed))
    except IDSplatError:
        # Made by another generator version: this cache is the project's own, so replace it
        # (written to a temporary folder, then renamed). A bad preset raises again, as it should.
        return Path(generate_sequence(parent, preset=preset, seed=seed, overwrite=True))
