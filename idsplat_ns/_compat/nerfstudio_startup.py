"""nerfstudio's external-method placeholders made cheap to build.

``nerfstudio.configs.external_methods`` builds one ``ExternalMethodDummyTrainerConfig`` per listed
third-party method (26 in nerfstudio 1.1.5) while ``method_configs`` is imported, that is at every
``ns-train``, ``ns-eval`` and ``ns-viewer`` start. Its ``__post_init__`` asks who called it with
``inspect.stack()``, which reads the source lines of every frame on the stack: 3-5 s of each start
on a 2-core machine. The caller's name is the same question answered from the frame itself, with
no file read; everything else (the install offer when the user picks such a method) is unchanged.
"""

from __future__ import annotations

import sys
from types import ModuleType


def speed_up_external_methods(module: ModuleType) -> None:
    """Replace the placeholder's ``__post_init__`` with one that skips the stack walk where
    nerfstudio's own ``get_external_methods`` builds it (the original returns there too)."""
    cls = getattr(module, "ExternalMethodDummyTrainerConfig", None)
    original = getattr(cls, "__post_init__", None)
    if original is None or getattr(original, "_idsplat_fast", False):
        return  # another nerfstudio layout, or already done: leave it as it is

    def __post_init__(self) -> None:
        # Frames: 0 this function, 1 the dataclass __init__, 2 its caller (inspect.stack()[2] in nerfstudio).
        if sys._getframe(2).f_code.co_name == "get_external_methods":
            return
        original(self)

    __post_init__._idsplat_fast = True  # type: ignore[attr-defined]
    cls.__post_init__ = __post_init__
