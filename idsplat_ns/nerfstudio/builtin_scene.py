"""The built-in synthetic street: made on first use, cached, reused afterwards."""

from __future__ import annotations

import os
from pathlib import Path

from rich.console import Console

CONSOLE = Console()


def cache_root() -> Path:
    """Where generated scenes are kept: ``$IDSPLAT_CACHE`` or ``~/.cache/idsplat_ns``."""
    return Path(os.environ.get("IDSPLAT_CACHE", Path.home() / ".cache" / "idsplat_ns")).expanduser()


def builtin_street(preset: str = "small", seed: int = 0) -> Path:
    """Path to the built-in street of ``preset``/``seed``, generating it the first time."""
    from idsplat_ns.data.synthetic import generate_sequence, get_preset, sequence_name

    parent = cache_root() / "synthetic"
    folder = parent / sequence_name(get_preset(preset), seed)
    # The generator writes atomically (temporary folder, then rename): a folder that exists is complete.
    if (folder / "idsplat_extras" / "generator.json").is_file():
        return folder
    CONSOLE.print(f"[bold]Generating the built-in synthetic street ({preset}, seed {seed}) in {folder} ...")
    parent.mkdir(parents=True, exist_ok=True)
    return Path(generate_sequence(parent, preset=preset, seed=seed))
