"""How messages name a preprocessing setting: as ns-train spells it. ``idsplat-preprocess`` takes
the same options with ``--preprocess.`` in place of the prefix (docs/instances.md)."""

from __future__ import annotations

PREFIX = "--pipeline.datamanager.preprocess."


def cli_option(name: str) -> str:
    """``masks.kind`` -> ``--pipeline.datamanager.preprocess.masks.kind``."""
    return PREFIX + name
