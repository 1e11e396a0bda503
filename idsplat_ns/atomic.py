"""Write files and folders atomically: to a temporary name next to the target, renamed on
success and removed on failure, so an interrupted run never leaves a half-written result; and
check, before any work, that an output can be written at all."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import uuid
from pathlib import Path
from typing import Iterator

from idsplat_ns.errors import IDSplatError

TMP_MARK = ".tmp-"


@contextlib.contextmanager
def atomic_path(final: Path) -> Iterator[Path]:
    """Yield a temporary path next to ``final``; on success it is renamed to ``final`` (files and
    folders alike), on any error it is removed."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.with_name(f"{final.name}{TMP_MARK}{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        yield tmp
        if final.is_dir():  # another process finished first: keep theirs
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except BaseException:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        elif tmp.exists():
            tmp.unlink()
        raise


def first_created(path: Path) -> Path:
    """The outermost folder of ``path`` that does not exist yet (``path`` itself when its parent
    exists): what making ``path`` would create, and all a failure should remove."""
    path = Path(path).absolute()
    top = path
    while not top.parent.exists() and top.parent != top:
        top = top.parent
    return top


def check_writable(path: Path, option: str, folder: bool) -> None:
    """One line naming ``option`` unless ``path`` can be written as a folder (``folder``) or a file:
    it is not the other kind already, and the nearest existing folder above it is a writable folder."""
    path = Path(path)
    kind = "folder" if folder else "file"
    if path.exists() and path.is_dir() != folder:
        other = "a folder" if path.is_dir() else "a file"
        raise IDSplatError(f"{option} {path}: is {other}, not a {kind}; give another path")
    above = first_created(path).parent if not path.exists() else path.parent
    if not above.is_dir():
        raise IDSplatError(f"{option} {path}: {above} is not a folder; give another path")
    target = path if path.exists() and folder else above
    try:  # a real write answers for permissions, ACLs and read-only mounts alike (os.access does not for root)
        with tempfile.TemporaryFile(dir=target):
            pass
    except OSError as err:
        raise IDSplatError(f"{option} {path}: {target} is not writable ({err.strerror}); give a {kind} in a folder "
                           "you can write to") from None


@contextlib.contextmanager
def removed_on_failure(folder: Path) -> Iterator[Path]:
    """Yield ``folder``; if the block fails, remove what of it did not exist before (nothing of a
    folder that was already there: the block must then write atomically)."""
    folder = Path(folder)
    created = None if folder.exists() else first_created(folder)
    try:
        yield folder
    except BaseException:
        if created is not None and created.exists():
            shutil.rmtree(created, ignore_errors=True)
        raise
