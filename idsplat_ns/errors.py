"""The one exception type for expected bad input (a missing file, a corrupt record, a wrong option).

Its message is a single line that names the file or option and says what to do. Command-line entry
points catch it and print ``error: <message>`` without a traceback (see :func:`run_cli`).
"""

from __future__ import annotations

import atexit
import os
import shutil
import sys
from pathlib import Path
from types import TracebackType
from typing import Callable, Optional, TypeVar

T = TypeVar("T")
Translator = Callable[[type, BaseException, Optional[TracebackType]], Optional[str]]
"""Turns an uncaught exception of code the project does not own into one line (None: not its case)."""


class IDSplatError(Exception):
    """Expected bad input; ``str(err)`` is one line naming the file or option and what to do."""

    def __init__(self, message: str) -> None:
        # Messages quote library errors (pickle, arrow, protobuf) that may span lines: fold them,
        # so the promise of one line holds whatever a damaged file makes a library say.
        super().__init__(" ".join(str(message).split()))


def run_cli(main: Callable[[], T]) -> T:
    """Run a command-line ``main``; an :class:`IDSplatError` ends in one line on stderr and exit 2."""
    try:
        return main()
    except IDSplatError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None


_run_dirs: list[tuple[Path, Path]] = []
"""(run folder, the outermost folder this process created for it); removed if the run fails before
a checkpoint."""


def register_run_dir(run_dir: Path, created: Path) -> None:
    """Remember a run folder this process has just created (``ns-train`` writes config.yml first),
    with ``created``, the outermost folder that did not exist before (:func:`idsplat_ns.atomic.first_created`, asked
    before the run folder was made; ``--output-dir`` itself when ns-train made it).

    If the process then dies of an uncaught exception before any checkpoint exists, the hook
    removes the run folder and then its parents that it leaves empty, up to and including
    ``created``, so a failed run leaves nothing the command made behind it.
    """
    _run_dirs.append((Path(run_dir).absolute(), Path(created).absolute()))


def remove_failed_runs() -> list[Path]:
    """Remove the registered run folders that hold no checkpoint; returns those removed."""
    removed = []
    while _run_dirs:
        run_dir, created = _run_dirs.pop()
        if not run_dir.is_dir() or next(run_dir.rglob("*.ckpt"), None) is not None:
            continue  # a checkpoint makes the run resumable: keep it
        shutil.rmtree(run_dir, ignore_errors=True)
        removed.append(run_dir)
        if run_dir == created or created not in run_dir.parents:
            continue
        parent = run_dir.parent
        while True:
            try:
                parent.rmdir()  # only if empty: other runs of the same experiment stay
            except OSError:
                break
            if parent == created:
                break
            parent = parent.parent
    return removed


_translators: list[Translator] = []
_cleanups: list[Callable[[Optional[TracebackType]], None]] = []


def one_line(exc_type: type, exc: BaseException, tb: Optional[TracebackType] = None) -> Optional[str]:
    """The one-line message of an expected failure, None for a bug (which keeps its traceback)."""
    if issubclass(exc_type, IDSplatError):
        return str(exc)
    for translate in _translators:
        line = translate(exc_type, exc, tb)
        if line is not None:
            return " ".join(line.split())
    if issubclass(exc_type, FileNotFoundError) and getattr(exc, "filename", None):
        # nerfstudio opens --load-config (ns-eval, ns-train, ns-render) without a check of its own.
        return f"{exc.filename}: no such file; check the path (--load-config takes a run's config.yml)"
    return None


def install_excepthook(*translators: Translator, cleanups: tuple[Callable[[Optional[TracebackType]], None], ...] = ()) -> None:
    """Make an uncaught :class:`IDSplatError` (or a missing file, or what one of ``translators``
    recognises) print one line (no traceback) and exit with status 2; any uncaught exception also
    removes a run folder this process registered that has no checkpoint yet (:func:`register_run_dir`)
    and runs each of ``cleanups`` on its traceback (what a third-party command made before failing).

    Used where the project does not own the entry point (``ns-train``, ``ns-eval``); every other
    exception keeps Python's usual report.
    """
    _translators.extend(t for t in translators if t not in _translators)
    _cleanups.extend(c for c in cleanups if c not in _cleanups)
    previous = sys.excepthook
    if getattr(previous, "_idsplat", False):
        return

    def hook(exc_type, exc, tb):
        for cleanup in _cleanups:
            cleanup(tb)
        message = one_line(exc_type, exc, tb)
        if message is not None:
            print(f"error: {message}", file=sys.stderr)
            sys.stderr.flush()
            # Status 2 like run_cli. Exit handlers (log writers) run first, then the failed run's
            # folder goes; os._exit ends the process even if a library left non-daemon threads (a
            # viewer server) running.
            atexit._run_exitfuncs()
            remove_failed_runs()
            os._exit(2)
        remove_failed_runs()
        previous(exc_type, exc, tb)

    hook._idsplat = True  # type: ignore[attr-defined]
    sys.excepthook = hook
