"""Fail early, in one line, when ``ns-render`` cannot write its output.

nerfstudio's ``ns-render`` (1.1.5) checks for ffmpeg in every mode, ``--output-format images``
included, but only after loading the data and the model, and then prints two lines and exits
with status 1. The model calls :func:`check_render_tools` while it is built, so the same condition
ends at once with the project's one-line error (``error: ...``, status 2, see
:mod:`idsplat_ns.errors`). Other commands (``ns-train``, ``ns-eval``, ``ns-viewer``) are not
affected: they do not need ffmpeg.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from idsplat_ns.errors import IDSplatError


def check_render_tools(argv0: str | None = None) -> None:
    """Raise :class:`IDSplatError` when running as ``ns-render`` and ffmpeg is not on the PATH."""
    program = Path(argv0 if argv0 is not None else (sys.argv[0] if sys.argv else "")).name
    if program == "ns-render" and shutil.which("ffmpeg") is None:
        raise IDSplatError("ns-render needs ffmpeg on the PATH (nerfstudio checks for it even with --output-format "
                           "images); install it (e.g. apt install ffmpeg) and run ns-render again")
