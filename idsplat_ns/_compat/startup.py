"""An import hook that applies the guards just before torchvision or open3d is first imported, and
nerfstudio's start-up fix just after ``nerfstudio.configs.external_methods`` is loaded.

Installed at interpreter start by ``idsplat_ns_compat.pth`` (written by ``idsplat-install-compat``,
which ``make install`` runs). It costs nothing until one of those modules is imported and never
imports torch itself before then.
"""

from __future__ import annotations

import sys
from importlib.abc import Loader, MetaPathFinder
from importlib.machinery import PathFinder

PTH_NAME = "idsplat_ns_compat.pth"
_NERFSTUDIO_EXTERNAL_METHODS = "nerfstudio.configs.external_methods"  # see nerfstudio_startup.py
_GUARDED = (_NERFSTUDIO_EXTERNAL_METHODS, "torchvision", "open3d")


class _GuardFinder(MetaPathFinder):
    """Runs the matching guard on the first import of a guarded top-level package, then steps aside."""

    def __init__(self) -> None:
        self._done: set[str] = set()

    def find_spec(self, fullname, path=None, target=None):  # noqa: D401 - importlib protocol
        if fullname not in _GUARDED or fullname in self._done:
            return None
        if any(type(f).__name__ == type(self).__name__ and f is not self for f in sys.meta_path):
            # Another copy of this finder, installed by another revision's own code (its install()
            # tells copies apart by class): it guards, so that no guard runs twice.
            return None
        if fullname == _NERFSTUDIO_EXTERNAL_METHODS:
            self._done.add(fullname)
            from idsplat_ns._compat.nerfstudio_startup import speed_up_external_methods

            spec = PathFinder.find_spec(fullname, path)
            if spec is not None and spec.loader is not None:
                spec.loader = _ThenPatch(spec.loader, speed_up_external_methods)
            return spec
        self._done.add(fullname)
        if fullname == "torchvision":
            from idsplat_ns._compat.torchvision_ops import ensure_importable

            ensure_importable()
        else:  # open3d
            from idsplat_ns._compat.libusb import ensure_loadable

            ensure_loadable()
        return None  # let the normal finders import the package


class _ThenPatch(Loader):
    """A module's own loader, then ``patch(module)`` once the module has run."""

    def __init__(self, loader: Loader, patch) -> None:
        self._loader, self._patch = loader, patch

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        self._patch(module)

    def __getattr__(self, name):  # get_source, get_filename...: the real loader's
        return getattr(self._loader, name)


def install() -> None:
    """Put the guard finder first on ``sys.meta_path`` (idempotent: by name, since the finder the
    start-up hook installed may come from a copy of this module that is no longer imported)."""
    if not any(type(f).__name__ == _GuardFinder.__name__ for f in sys.meta_path):
        sys.meta_path.insert(0, _GuardFinder())


def install_at_start_up() -> None:
    """The ``.pth`` file's call: :func:`install`, then the project's modules are forgotten again, so
    that a program imports ``idsplat_ns`` from wherever its own path says (``python -m`` in another
    revision's tree gets that tree's), not from the installed copy the hook was read from. The
    finder keeps working: it imports what it needs by name when a guarded module is imported."""
    install()
    for name in [n for n in sys.modules if n == "idsplat_ns" or n.startswith("idsplat_ns.")]:
        del sys.modules[name]


def write_pth(site_packages: str | None = None) -> str:
    """Write the ``.pth`` file that installs the hook at start-up into ``site_packages``; returns its path."""
    import sysconfig  # this module runs at every Python start: only what install() needs is imported at the top
    from pathlib import Path

    from idsplat_ns.atomic import atomic_path

    target = Path(site_packages or sysconfig.get_paths()["purelib"]) / PTH_NAME
    with atomic_path(target) as tmp:
        tmp.write_text("import idsplat_ns._compat.startup as _idsplat_startup; _idsplat_startup.install_at_start_up()\n")
    return str(target)


def main() -> None:
    """Console script ``idsplat-install-compat``: write the start-up hook into this environment."""
    print(f"wrote {write_pth()}")
