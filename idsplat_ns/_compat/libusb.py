"""Let open3d import on machines without ``libusb-1.0.so.0`` (its wheel links against it).

If the system has libusb, nothing happens. Otherwise the copy shipped by the ``libusb-package``
wheel is loaded globally, which satisfies open3d's dependency by its soname.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import importlib.util
from pathlib import Path

_HANDLE = None


def ensure_loadable() -> bool:
    """Preload a libusb if the dynamic loader cannot find one. Returns True if it acted."""
    global _HANDLE
    if _HANDLE is not None:
        return False
    try:
        ctypes.CDLL("libusb-1.0.so.0")
        return False  # the system has it
    except OSError:
        pass
    spec = importlib.util.find_spec("libusb_package")
    if spec is None or spec.origin is None:
        return False  # open3d's own ImportError will name the missing library
    candidates = sorted(Path(spec.origin).parent.glob("libusb-1.0*.so*"))
    if not candidates:
        return False
    _HANDLE = ctypes.CDLL(str(candidates[0]), mode=ctypes.RTLD_GLOBAL)
    return True


def import_open3d():
    """open3d, imported on first use (seconds: cached runs never need it), after this guard (a
    no-op where the system has libusb), in case the start-up hook is not installed."""
    ensure_loadable()
    import open3d

    return open3d
