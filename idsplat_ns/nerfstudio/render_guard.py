"""ffmpeg for ``ns-render``, made available before nerfstudio looks for it.

nerfstudio's ``ns-render`` (1.1.5) checks for ffmpeg in every mode, ``--output-format images``
included, but only after loading the data and the model, and then prints two lines and exits
with status 1. The model calls :func:`check_render_tools` while it is built: it puts the ffmpeg
that the install ships on the PATH when the system has none (:mod:`idsplat_ns._compat.ffmpeg`),
and a broken install ends at once with the project's one-line error. Other commands
(``ns-train``, ``ns-eval``, ``ns-viewer``) do not need ffmpeg.
"""

from __future__ import annotations

import sys
from pathlib import Path

from idsplat_ns._compat.ffmpeg import ensure_ffmpeg_on_path


def check_render_tools(argv0: str | None = None) -> None:
    """When running as ``ns-render``, make sure an ``ffmpeg`` is on the PATH (one-line error if
    none can be had)."""
    program = Path(argv0 if argv0 is not None else (sys.argv[0] if sys.argv else "")).name
    if program == "ns-render":
        ensure_ffmpeg_on_path()
