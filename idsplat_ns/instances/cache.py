"""Atomic, content-keyed stage caches for the preprocessing runner.

Each stage result is stored under ``<cache_dir>/<stage>-<key>.<ext>`` (a file or a folder) where the
key hashes the stage's inputs and settings. Results are written under a temporary name in the same
folder and renamed into place, so a run killed midway leaves at most a temporary that is never read
(and is removed by the next run), never a half-written result.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np

from idsplat_ns import __version__
from idsplat_ns.atomic import TMP_MARK, atomic_path  # noqa: F401 (re-exported for the stage caches)
from idsplat_ns.data.scene import Scene



def hash_json(obj) -> str:
    """Short stable hash of a JSON-serialisable object (paths and tuples are stringified) and of
    the package version, so that a new release never reuses caches of another one's algorithms."""
    text = json.dumps({"idsplat_ns": __version__, "key": obj}, sort_keys=True, default=str)
    return hashlib.blake2b(text.encode(), digest_size=10).hexdigest()


def scene_fingerprint(scene: Scene) -> str:
    """Hash of everything in a scene that the instance stages read: frames, poses, lidar points,
    image identities (path, size, modification time or bytes) and camera models."""
    h = hashlib.blake2b(digest_size=12)
    h.update(f"{scene.name}|{scene.source}|{scene.root}".encode())
    for arr in (scene.frame_indices, scene.frame_times, scene.ego_poses):
        h.update(np.ascontiguousarray(arr).tobytes())
    for im in scene.images:
        K = im.intrinsics
        h.update(f"{im.camera}|{im.frame_index}|{im.time!r}|{K}".encode())
        h.update(np.ascontiguousarray(im.camera_to_world).tobytes())
        if im.image_path is not None:
            p = Path(im.image_path)
            st = p.stat() if p.exists() else None
            h.update(f"{p}|{st.st_size if st else -1}|{st.st_mtime_ns if st else -1}".encode())
        elif im.image_bytes is not None:
            h.update(hashlib.blake2b(im.image_bytes, digest_size=12).digest())
        elif im.image is not None:
            h.update(np.ascontiguousarray(im.image).tobytes())
    for sw in scene.lidar:
        h.update(f"{sw.frame_index}|{sw.time!r}".encode())
        for arr in (sw.origins, sw.directions, sw.ranges, sw.returned):
            h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(cache_dir: Path) -> int:
    """Delete temporaries left by runs that were killed (their process is gone); returns the count."""
    removed = 0
    if not Path(cache_dir).is_dir():
        return 0
    for p in Path(cache_dir).iterdir():
        if TMP_MARK not in p.name:
            continue
        try:
            pid = int(p.name.split(TMP_MARK)[1].split("-")[0])
        except ValueError:
            continue
        if pid != os.getpid() and not _pid_alive(pid):
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
            removed += 1
    return removed


META_KEY = "meta_json"


def save_npz(path: Path, arrays: dict[str, np.ndarray], meta: dict, compress: bool = True) -> None:
    """Write named arrays plus a JSON-able ``meta`` dict (stored as bytes under ``META_KEY``) to one .npz."""
    payload = dict(arrays)
    payload[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    with open(path, "wb") as fh:
        (np.savez_compressed if compress else np.savez)(fh, **payload)


def load_npz(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """Read a file written by :func:`save_npz`: its arrays (in memory) and its meta dict."""
    with np.load(path) as data:
        meta = json.loads(bytes(data[META_KEY]).decode())
        arrays = {name: data[name] for name in data.files if name != META_KEY}
    return arrays, meta
