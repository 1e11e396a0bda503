"""One line, not a traceback, for what fails inside nerfstudio's own commands on an IDSplat run.

``ns-eval``, ``ns-render``, ``ns-viewer`` and ``ns-export`` are nerfstudio's entry points: the
project cannot check their arguments before they work. These translators, given to
:func:`idsplat_ns.errors.install_excepthook` by ``method_configs``, recognise the failure by the
nerfstudio function it passed through and say in one line what is wrong and what to do; any other
failure keeps its traceback.
"""

from __future__ import annotations

import time
from pathlib import Path
from types import FrameType, TracebackType
from typing import Optional

from idsplat_ns.runs.checkpoints import checkpoint_problem

_LOADED_AT = time.time()
"""When the plugin was loaded: nerfstudio's command had not made its output folder yet."""


def _frame_in(tb: Optional[TracebackType], module: str, function: Optional[str] = None) -> Optional[FrameType]:
    """The innermost frame of ``module`` (and ``function``) in a traceback, or None."""
    found = None
    while tb is not None:
        frame = tb.tb_frame
        if frame.f_globals.get("__name__") == module and function in (None, frame.f_code.co_name):
            found = frame
        tb = tb.tb_next
    return found


def explain_checkpoint_load(exc_type: type, exc: BaseException, tb: Optional[TracebackType]) -> Optional[str]:
    """A failure in nerfstudio's checkpoint loader (``eval_load_checkpoint``: newest name, every
    name in the folder read as a step) that the run's checkpoint folder explains."""
    frame = _frame_in(tb, "nerfstudio.utils.eval_utils", "eval_load_checkpoint")
    folder = getattr(frame.f_locals.get("config") if frame is not None else None, "load_dir", None)
    return None if folder is None else checkpoint_problem(Path(folder))


def explain_export(exc_type: type, exc: BaseException, tb: Optional[TracebackType]) -> Optional[str]:
    """``ns-export`` on an IDSplat run: its exporters expect splatfacto's single set of Gaussians
    (or a NeRF's rays); an IDSplat scene is a static set plus instances on trajectories."""
    frame = _frame_in(tb, "nerfstudio.scripts.exporter")
    if frame is None:
        return None
    pipeline = frame.f_locals.get("pipeline")
    model = getattr(pipeline, "model", None)
    if model is None or not type(model).__module__.startswith("idsplat_ns."):
        return None
    config = getattr(frame.f_locals.get("self"), "load_config", "RUN/config.yml")
    return (f"ns-export does not export IDSplat runs (a static set of Gaussians plus instances on trajectories); "
            f"run idsplat-export --load-config {config} --output-dir DIR (.ply files and trajectories.json)")


def remove_export_folder(tb: Optional[TracebackType]) -> None:
    """``ns-export`` makes its ``--output-dir`` before it loads the run: when it then fails, that
    folder goes again if it is empty and was made by this process (an excepthook cleanup)."""
    frame = _frame_in(tb, "nerfstudio.scripts.exporter")
    out = getattr(frame.f_locals.get("self") if frame is not None else None, "output_dir", None)
    if out is None or not Path(out).is_dir() or any(Path(out).iterdir()) or Path(out).stat().st_mtime < _LOADED_AT:
        return
    Path(out).rmdir()
