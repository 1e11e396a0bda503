"""ffmpeg for ``ns-render`` and ``idsplat-render-drive`` without a system package.

nerfstudio checks ``shutil.which("ffmpeg")`` and mediapy runs ``ffmpeg`` by name, so a binary
must be on the PATH under that name. Where the system has none, the static build that the
``imageio-ffmpeg`` wheel ships (a dependency) is linked as ``ffmpeg`` into a private folder that
is put first on this process's PATH.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from idsplat_ns.errors import IDSplatError


def ensure_ffmpeg_on_path() -> str:
    """Path of the ``ffmpeg`` that this process will run (the system's, else imageio-ffmpeg's)."""
    found = shutil.which("ffmpeg")
    if found is not None:
        return found
    try:
        import imageio_ffmpeg
    except ImportError as err:  # a dependency: only a broken install gets here
        raise IDSplatError(f"no ffmpeg on the PATH and imageio-ffmpeg cannot be imported ({err}); "
                           "reinstall with `make install` or `apt-get install ffmpeg`") from None
    exe = Path(imageio_ffmpeg.get_ffmpeg_exe())
    folder = Path(tempfile.gettempdir()) / f"idsplat-ffmpeg-{os.getuid()}"
    folder.mkdir(exist_ok=True)
    link = folder / "ffmpeg"
    if not link.exists() or link.resolve() != exe.resolve():
        tmp = folder / f"ffmpeg.tmp-{os.getpid()}"
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(exe)
        tmp.replace(link)  # atomic: concurrent processes never see a half-made link
    os.environ["PATH"] = f"{folder}{os.pathsep}{os.environ.get('PATH', '')}"
    return str(link)
