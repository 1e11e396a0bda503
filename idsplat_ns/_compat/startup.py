"""An import hook that applies the guards just before torchvision or open3d is first imported.

Installed at interpreter start by ``idsplat_ns_compat.pth`` (written by ``idsplat-install-compat``,
which ``make install`` runs). It costs nothing until one of the two packages is imported and never
imports torch itself before then.
"""

from __future__ import annotations

import sys
from importlib.abc import MetaPathFinder

PTH_NAME = "idsplat_ns_compat.pth"


class _GuardFinder(MetaPathFinder):
    """Runs the matching guard on the first import of a guarded top-level package, then steps aside."""

    def __init__(self) -> None:
        self._done: set[str] = set()

    def find_spec(self, fullname, path=None, target=None):  # noqa: D401 - importlib protocol
        if fullname in ("torchvision", "open3d") and fullname not in self._done:
            self._done.add(fullname)
            if fullname == "torchvision":
                from idsplat_ns._compat.torchvision_ops import ensure_importable

                ensure_importable()
            else:
                from idsplat_ns._compat.libusb import ensure_loadable

                ensure_loadable()
        return None  # let the normal finders import the package


def install() -> None:
    """Put the guard finder first on ``sys.meta_path`` (idempotent)."""
    if not any(isinstance(f, _GuardFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _GuardFinder())


def write_pth(site_packages: str | None = None) -> str:
    """Write the ``.pth`` file that installs the hook at start-up into ``site_packages``; returns its path."""
    import sysconfig
    from pathlib import Path

    from idsplat_ns.atomic import atomic_path

    target = Path(site_packages or sysconfig.get_paths()["purelib"]) / PTH_NAME
    with atomic_path(target) as tmp:
        tmp.write_text("import idsplat_ns._compat.startup as _idsplat_startup; _idsplat_startup.install()\n")
    return str(target)


def main() -> None:
    """Console script ``idsplat-install-compat``: write the start-up hook into this environment."""
    print(f"wrote {write_pth()}")
