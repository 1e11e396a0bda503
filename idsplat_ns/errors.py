"""The one exception type for expected bad input (a missing file, a corrupt record, a wrong option).

Its message is a single line that names the file or option and says what to do. Command-line entry
points catch it and print ``error: <message>`` without a traceback (see :func:`run_cli`).
"""

from __future__ import annotations

import atexit
import os
import sys
from typing import Callable, TypeVar

T = TypeVar("T")


class IDSplatError(Exception):
    """Expected bad input; ``str(err)`` is one line naming the file or option and what to do."""


def run_cli(main: Callable[[], T]) -> T:
    """Run a command-line ``main``; an :class:`IDSplatError` ends in one line on stderr and exit 2."""
    try:
        return main()
    except IDSplatError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None


def install_excepthook() -> None:
    """Make an uncaught :class:`IDSplatError` print one line (no traceback) and exit with status 2.

    Used where the project does not own the entry point (``ns-train``, ``ns-eval``); every other
    exception keeps Python's usual report.
    """
    previous = sys.excepthook
    if getattr(previous, "_idsplat", False):
        return

    def hook(exc_type, exc, tb):
        if issubclass(exc_type, IDSplatError):
            print(f"error: {exc}", file=sys.stderr)
            sys.stderr.flush()
            # Status 2 like run_cli. Exit handlers (log writers) run first; os._exit then ends the
            # process even if a library left non-daemon threads (a viewer server) running.
            atexit._run_exitfuncs()
            os._exit(2)
        previous(exc_type, exc, tb)

    hook._idsplat = True  # type: ignore[attr-defined]
    sys.excepthook = hook
