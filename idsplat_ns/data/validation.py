"""Checks of values read from a dataset, applied once at the boundary by each reader.

Every check is pure (arrays in, arrays or nothing out) and raises :class:`IDSplatError` with one
line naming the file, the frame and the field, so bad data stops before training rather than
training silently on NaN poses or a zero focal length. Readers call these right where they know
the file and frame; the checks themselves know nothing about formats.
"""

from __future__ import annotations

import errno
import os
import sys
from pathlib import Path
from typing import Iterable, Mapping, Optional, Sequence

import numpy as np

from idsplat_ns.errors import IDSplatError

ROTATION_WARN_TOL = 1e-4
"""Deviation of R^T R from I (max abs) above which a rotation is renormalised, with a warning
(below it, float rounding of stored poses: left as is)."""
ROTATION_REJECT_TOL = 1e-2
"""Deviation above which a rotation is not a rotation at all: the file is damaged, not imprecise."""
QUATERNION_WARN_TOL = 1e-3
"""|norm - 1| of a stored quaternion above which the renormalisation is worth a warning."""


def _at(where: str, frame: Optional[int], field: str) -> str:
    """The message prefix ``file: frame N: field`` (the frame left out when not per frame)."""
    return f"{where}: frame {frame}: {field}" if frame is not None else f"{where}: {field}"


_warned: set[str] = set()


def warn(message: str, key: Optional[str] = None) -> None:
    """One line on stderr: the data is used, but a user should know it was corrected.

    ``key`` (a file and field) is warned about once, not once per frame of a long sequence.
    """
    key = key or message
    if key in _warned:
        return
    _warned.add(key)
    print(f"warning: {message}", file=sys.stderr)


def check_finite(values: np.ndarray, where: str, field: str, frame: Optional[int] = None) -> np.ndarray:
    """Raise if any value is NaN or infinite; returns the values as a float64 array."""
    arr = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        first = np.argwhere(bad)[0]
        index = f" (entry {tuple(int(i) for i in first)})" if arr.ndim > 1 else (f" (entry {int(first[0])})" if arr.ndim == 1 else "")
        raise IDSplatError(
            f"{_at(where, frame, field)}: {int(bad.sum())} value(s) not finite{index}, e.g. {arr[tuple(first)]}; "
            "the file is damaged: re-download or regenerate it"
        )
    return arr


def check_rotation(R: np.ndarray, where: str, field: str, frame: Optional[int] = None) -> np.ndarray:
    """A 3x3 rotation: finite, orthonormal, right-handed; renormalised (warning) when slightly off.

    Stored rotations lose digits in text formats; a nearly orthonormal matrix is projected back
    onto SO(3) (nearest rotation by SVD) rather than rejected, but one far off is a damaged file.
    """
    R = check_finite(R, where, field, frame)
    deviation = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if deviation > ROTATION_REJECT_TOL or det <= 0:
        raise IDSplatError(
            f"{_at(where, frame, field)}: not a rotation (|R^T R - I| = {deviation:.3g}, det = {det:.3g}); "
            "the file is damaged: re-download or regenerate it"
        )
    if deviation > ROTATION_WARN_TOL:
        warn(f"{_at(where, frame, field)}: rotation off orthonormal by {deviation:.2g}; renormalised (further ones not shown)", f"{where}:{field}")
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
    return R


def check_pose(T: np.ndarray, where: str, field: str, frame: Optional[int] = None) -> np.ndarray:
    """A 4x4 rigid transform: finite, rotation block checked (and renormalised), last row 0 0 0 1."""
    T = check_finite(T, where, field, frame).copy()
    if T.shape != (4, 4):
        raise IDSplatError(f"{_at(where, frame, field)}: shape {T.shape}, expected a 4x4 matrix")
    if np.abs(T[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-6:
        raise IDSplatError(f"{_at(where, frame, field)}: last row {T[3].tolist()} is not 0 0 0 1; not a rigid transform")
    T[:3, :3] = check_rotation(T[:3, :3], where, field, frame)
    return T


def check_quaternion(q: np.ndarray, where: str, field: str, frame: Optional[int] = None) -> np.ndarray:
    """A wxyz quaternion: finite and of non-zero norm; returned unit-normalised (warning if far from 1)."""
    q = check_finite(q, where, field, frame)
    norm = float(np.linalg.norm(q))
    if norm < 1e-6:
        raise IDSplatError(f"{_at(where, frame, field)}: quaternion of zero norm is not a rotation; the file is damaged")
    if abs(norm - 1.0) > QUATERNION_WARN_TOL:
        warn(f"{_at(where, frame, field)}: quaternion norm {norm:.4g}, not 1; renormalised (further ones not shown)", f"{where}:{field}")
    return q / norm


def check_regular_file(path: Path, what: str, hint: str) -> None:
    """One line unless ``path`` is a regular file (a link to one included): says what it is instead
    (missing, a folder, a broken link, a link loop), then ``hint``."""
    path = Path(path)
    try:
        if path.is_file():
            return
        os.stat(path)  # exists but is not a file: a folder, a device...
        kind = "a folder" if path.is_dir() else "not a regular file"
    except OSError as err:
        if err.errno == errno.ELOOP:
            kind = "a symbolic link loop"
        elif path.is_symlink():
            kind = f"a broken symbolic link (to {os.readlink(path)})"
        else:
            kind = "missing"
    raise IDSplatError(f"{path}: {what} is {kind}; {hint}")


def check_intrinsics(
    fx: float, fy: float, cx: float, cy: float, width: int, height: int, where: str, frame: Optional[int] = None
) -> None:
    """Focal lengths positive and finite, image size positive, principal point inside the image."""
    for name, value in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)):
        check_finite(np.asarray(value), where, name, frame)
    for name, value in (("fx", fx), ("fy", fy)):
        if not value > 0:
            raise IDSplatError(f"{_at(where, frame, name)}: focal length {value} must be > 0 (pixels); fix the intrinsics")
    for name, value in (("width", width), ("height", height)):
        if not value > 0:
            raise IDSplatError(f"{_at(where, frame, name)}: image {name} {value} must be > 0")
    for name, value, size in (("cx", cx, width), ("cy", cy, height)):
        if not 0 <= value <= size:
            raise IDSplatError(
                f"{_at(where, frame, name)}: principal point {value} is outside the image [0, {size}]; fix the intrinsics"
            )


def check_timestamps(times: Sequence[float], where: str, field: str = "timestamps") -> np.ndarray:
    """Finite and strictly increasing; a repeated or backwards stamp is named by its frame index."""
    t = check_finite(np.asarray(times, dtype=np.float64).reshape(-1), where, field)
    steps = np.diff(t)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        kind = "duplicates" if steps[k - 1] == 0 else "goes back from"
        raise IDSplatError(
            f"{_at(where, k, field)}: {t[k]!r} {kind} frame {k - 1} ({t[k - 1]!r}); timestamps must increase"
        )
    return t


def check_frame_counts(counts: Mapping[str, int], expected: int, where: str) -> None:
    """Each source (a file path or a sensor) holds at least ``expected`` frames."""
    short = {name: n for name, n in counts.items() if n < expected}
    if short:
        name, n = next(iter(short.items()))
        raise IDSplatError(f"{name}: {n} entries for {expected} frames (from {where}); the sequence is incomplete")


def check_image_sizes(sizes: Iterable[tuple[str, int, tuple[int, int]]]) -> None:
    """All images of one camera share one size: ``sizes`` holds (camera, frame, (w, h)) in frame order.

    The intrinsics are per camera, so an image of another size would be projected with the wrong K.
    """
    first: dict[str, tuple[int, tuple[int, int]]] = {}
    for camera, frame, size in sizes:
        if camera not in first:
            first[camera] = (frame, size)
        elif size != first[camera][1]:
            f0, s0 = first[camera]
            raise IDSplatError(
                f"{camera}: frame {frame}: image size {size[0]}x{size[1]} differs from frame {f0}'s {s0[0]}x{s0[1]}; "
                "all images of a camera must share one size"
            )


def check_columns(present: Iterable[str], needed: Sequence[str], where: str, what: str) -> None:
    """The named columns exist (lidar x, y, z, i, t, d; cuboid fields)."""
    have = set(present)
    missing = [c for c in needed if c not in have]
    if missing:
        raise IDSplatError(f"{where}: {what} lacks columns {missing}; expected {', '.join(needed)}")


MAX_LIDAR_RANGE_M = 10_000.0
"""A return farther than this from its sensor is a damaged value, not a measurement (real lidars
reach ~300 m); it would also overflow float32 geometry downstream."""
MAX_SWEEP_TIME_OFFSET_S = 1.0
"""A point time farther than this from its sweep's stamp is damaged (a sweep lasts ~0.1 s)."""


def check_within(values: np.ndarray, low: float, high: float, where: str, field: str, frame: Optional[int] = None,
                 unit: str = "") -> np.ndarray:
    """Finite and inside ``[low, high]``: a finite but absurd value (1e30 m) is damage all the same."""
    arr = check_finite(values, where, field, frame)
    bad = (arr < low) | (arr > high)
    if bad.any():
        i = int(np.argmax(bad.reshape(-1)))
        raise IDSplatError(
            f"{_at(where, frame, field)}: {int(bad.sum())} value(s) outside [{low:g}, {high:g}]{unit} (entry {i}: "
            f"{arr.reshape(-1)[i]:g}); the file is damaged: re-download or regenerate it"
        )
    return arr
