"""Waymo lidar range images: the MatrixFloat codec and range image <-> rays.

Conventions (facts of the format): row 0 is the highest beam, so the calibration's inclinations
(bottom first) are reversed; column ``c`` of ``W`` has azimuth
``pi * (2 (W - c - 0.5) / W - 1) - atan2(R10, R00)`` in the lidar frame (R the lidar-to-vehicle
rotation), so azimuth decreases with the column. A ray's direction in the lidar frame is
``(cos az cos inc, sin az cos inc, sin inc)``. Range <= 0 means no return. TOP's per-pixel pose
``(roll, pitch, yaw, x, y, z)`` is vehicle-to-world with ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import struct
import zlib
from typing import Optional

import numpy as np

from idsplat_ns.errors import IDSplatError

SWEEP_SECONDS = 0.1
"""One revolution of the TOP lidar (10 Hz)."""


# ---------------------------------------------------------------- MatrixFloat wire codec
# A MatrixFloat is field 1 (packed float32) and field 2 (MatrixShape: field 1 repeated int32).
# Decoding it by hand is ~100x faster than the pure-python protobuf runtime on ~10^6 floats.


def read_varint(buf: bytes, pos: int) -> tuple[int, int]:
    result, shift = 0, 0
    while True:
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7


def _encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        if value:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _parse_shape(buf: bytes) -> list[int]:
    dims, pos = [], 0
    while pos < len(buf):
        key, pos = read_varint(buf, pos)
        if key >> 3 == 1 and key & 7 == 0:
            v, pos = read_varint(buf, pos)
            dims.append(v)
        elif key >> 3 == 1 and key & 7 == 2:  # packed dims
            n, pos = read_varint(buf, pos)
            end = pos + n
            while pos < end:
                v, pos = read_varint(buf, pos)
                dims.append(v)
        else:
            raise ValueError(f"unexpected field {key >> 3} in MatrixShape")
    return dims


def parse_matrix_float(serialized: bytes) -> np.ndarray:
    """A serialized MatrixFloat as a float32 array of its shape (raises ValueError if malformed)."""
    data, dims, pos = [], None, 0
    while pos < len(serialized):
        key, pos = read_varint(serialized, pos)
        number, wire = key >> 3, key & 7
        if number == 1 and wire == 2:
            n, pos = read_varint(serialized, pos)
            data.append(np.frombuffer(serialized, dtype="<f4", count=n // 4, offset=pos))
            pos += n
        elif number == 1 and wire == 5:  # unpacked float, legal on the wire
            data.append(np.frombuffer(serialized, dtype="<f4", count=1, offset=pos))
            pos += 4
        elif number == 2 and wire == 2:
            n, pos = read_varint(serialized, pos)
            dims = _parse_shape(serialized[pos : pos + n])
            pos += n
        else:
            raise ValueError(f"unexpected field {number} (wire type {wire}) in MatrixFloat")
    values = np.concatenate(data) if data else np.zeros(0, np.float32)
    if dims is None or int(np.prod(dims)) != len(values):
        raise ValueError(f"MatrixFloat shape {dims} does not match its {len(values)} values")
    return values.astype(np.float32).reshape(dims)


def serialize_matrix_float(array: np.ndarray) -> bytes:
    """Serialize an array as a MatrixFloat (packed data, then shape), as Waymo's writer does."""
    arr = np.ascontiguousarray(array, dtype="<f4")
    payload = arr.tobytes()
    shape = b"".join(b"\x08" + _encode_varint(int(d)) for d in arr.shape)
    return b"\x0a" + _encode_varint(len(payload)) + payload + b"\x12" + _encode_varint(len(shape)) + shape


def decode_compressed_matrix(compressed: bytes, what: str) -> np.ndarray:
    """zlib-decompress and parse a MatrixFloat; ``what`` names it in the one-line error."""
    try:
        return parse_matrix_float(zlib.decompress(compressed))
    except (zlib.error, ValueError, IndexError, struct.error) as err:
        raise IDSplatError(f"{what}: corrupt compressed range image ({err}); the segment file is damaged") from None


def encode_compressed_matrix(array: np.ndarray, level: int = 6) -> bytes:
    """zlib(MatrixFloat(array)), the inverse of :func:`decode_compressed_matrix`."""
    return zlib.compress(serialize_matrix_float(array), level)


# ---------------------------------------------------------------- geometry


def row_inclinations(
    height: int, beam_inclinations: Optional[np.ndarray], inclination_min: float, inclination_max: float
) -> np.ndarray:
    """[H] inclination of each range-image row, row 0 at the top (radians)."""
    if beam_inclinations is not None and len(beam_inclinations) > 0:
        incl = np.asarray(beam_inclinations, dtype=np.float64)
        if len(incl) != height:
            raise IDSplatError(f"lidar calibration has {len(incl)} beam inclinations but the range image has {height} rows")
    else:  # uniform: row centres between min and max
        incl = inclination_min + (np.arange(height) + 0.5) / height * (inclination_max - inclination_min)
    return incl[::-1].copy()


def column_azimuths(width: int, lidar_to_vehicle: np.ndarray) -> np.ndarray:
    """[W] azimuth of each range-image column in the lidar frame (radians)."""
    az_correction = np.arctan2(lidar_to_vehicle[1, 0], lidar_to_vehicle[0, 0])
    ratios = (width - np.arange(width) - 0.5) / width
    return (ratios * 2.0 - 1.0) * np.pi - az_correction


def directions_lidar_frame(inclinations: np.ndarray, azimuths: np.ndarray) -> np.ndarray:
    """[H, W, 3] unit ray directions in the lidar frame."""
    ci, si = np.cos(inclinations)[:, None], np.sin(inclinations)[:, None]
    ca, sa = np.cos(azimuths)[None, :], np.sin(azimuths)[None, :]
    return np.stack([ca * ci, sa * ci, np.broadcast_to(si, (len(inclinations), len(azimuths)))], -1)


def euler_to_rotmat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """[..., 3, 3] = Rz(yaw) Ry(pitch) Rx(roll) (Waymo's 3-2-1 convention)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def pixel_pose_matrices(pixel_pose: np.ndarray) -> np.ndarray:
    """[H, W, 4, 4] vehicle-to-world from a [H, W, 6] (roll, pitch, yaw, x, y, z) pose image."""
    p = np.asarray(pixel_pose, dtype=np.float64)
    T = np.zeros(p.shape[:2] + (4, 4))
    T[..., :3, :3] = euler_to_rotmat(p[..., 0], p[..., 1], p[..., 2])
    T[..., :3, 3] = p[..., 3:6]
    T[..., 3, 3] = 1.0
    return T


def range_image_rays(
    ranges: np.ndarray,  # [H, W] metres, <= 0 for no return
    lidar_to_vehicle: np.ndarray,  # [4, 4]
    inclinations: np.ndarray,  # [H] row 0 top
    vehicle_to_world: np.ndarray,  # [4, 4] frame pose (used where pixel_pose is None)
    pixel_pose: Optional[np.ndarray] = None,  # [H, W, 6] per-pixel vehicle-to-world (TOP)
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World rays of every pixel: origins [H*W, 3], unit directions [H*W, 3], ranges [H*W], returned [H*W].

    With a pixel pose, each ray gets the vehicle pose at the time that pixel fired (ego motion
    within the sweep); otherwise all rays use ``vehicle_to_world``.
    """
    H, W = ranges.shape
    d_lidar = directions_lidar_frame(inclinations, column_azimuths(W, lidar_to_vehicle)).reshape(-1, 3)
    R_l, t_l = lidar_to_vehicle[:3, :3], lidar_to_vehicle[:3, 3]
    d_vehicle = d_lidar @ R_l.T
    if pixel_pose is not None:
        if pixel_pose.shape[:2] != (H, W):
            raise IDSplatError(f"TOP range image pose is {pixel_pose.shape[:2]}, range image is {(H, W)}: inconsistent frame")
        T = pixel_pose_matrices(pixel_pose).reshape(-1, 4, 4)
        directions = np.einsum("nij,nj->ni", T[:, :3, :3], d_vehicle)
        origins = np.einsum("nij,j->ni", T[:, :3, :3], t_l) + T[:, :3, 3]
    else:
        directions = d_vehicle @ vehicle_to_world[:3, :3].T
        origins = np.broadcast_to(vehicle_to_world[:3, :3] @ t_l + vehicle_to_world[:3, 3], directions.shape).copy()
    r = ranges.reshape(-1).astype(np.float64)
    returned = r > 0
    return origins, directions, np.where(returned, r, 0.0), returned


def column_fire_fractions(pixel_pose: Optional[np.ndarray], width: int) -> np.ndarray:
    """[W] when each column fired, as a fraction of the sweep in [0, 1).

    Waymo gives no per-pixel time, but the per-pixel pose moves with the ego: ordering columns by
    the ego's progress along its heading gives the firing order and the seam where the sweep
    starts. With no pose or a stationary ego (< 1 cm over the sweep, when the order does not
    change any geometry) the columns are taken to fire left to right from column 0.
    """
    default = (np.arange(width) + 0.5) / width
    if pixel_pose is None:
        return default
    trans = np.asarray(pixel_pose[..., 3:6], dtype=np.float64).mean(0)  # [W, 3]
    yaw = np.asarray(pixel_pose[..., 2], dtype=np.float64).mean()
    heading = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    progress = trans @ heading  # increases with time while driving forward
    if np.ptp(progress) < 0.01:
        return default
    steps = np.diff(progress, append=progress[:1])  # step from column c to c+1 (wrapping)
    forward = np.median(steps) > 0
    order = np.arange(width) if forward else np.arange(width)[::-1]
    seq_steps = np.diff(progress[order], append=progress[order][:1])
    seam = (int(np.argmin(seq_steps)) + 1) % width  # first column fired after the big backward jump
    rank = np.empty(width)
    rank[order] = (np.arange(width) - seam) % width
    return (rank + 0.5) / width


def pose_sweep_fraction(pixel_pose: Optional[np.ndarray], position: np.ndarray) -> float:
    """When in the sweep the vehicle was at ``position`` [3] (the frame pose's translation, in the
    pixel poses' frame), as a fraction of the sweep from its first column: the frame pose's own time.

    Waymo's ``Frame.pose`` is "roughly (but not exactly)" the pose in the middle of the sweep and
    carries no time of its own, while ``Frame.timestamp_micros`` is the sweep's start. The TOP
    lidar's per-pixel poses place the vehicle at each column's firing (:func:`column_fire_fractions`):
    a line fitted to fraction against progress along the heading gives the fraction where the
    frame pose lies (beyond [0, 1] where it lies outside the sweep). 0.5 without pixel poses or with
    a standing ego (< 1 cm over the sweep, where its time changes no position).
    """
    if pixel_pose is None:
        return 0.5
    trans = np.asarray(pixel_pose[..., 3:6], dtype=np.float64).mean(0)  # [W, 3]
    yaw = np.asarray(pixel_pose[..., 2], dtype=np.float64).mean()
    heading = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    progress = trans @ heading
    if np.ptp(progress) < 0.01:
        return 0.5
    fractions = column_fire_fractions(pixel_pose, trans.shape[0])
    slope, intercept = np.polyfit(progress, fractions, 1)
    return float(intercept + slope * (np.asarray(position, dtype=np.float64) @ heading))


def rays_to_range_image(
    points_lidar: np.ndarray,  # [N, 3] points in the lidar frame
    inclinations: np.ndarray,  # [H] row 0 top
    width: int,
    lidar_to_vehicle: np.ndarray,  # [4, 4] (for the azimuth offset)
    intensity: Optional[np.ndarray] = None,  # [N]
) -> np.ndarray:
    """[H, W, 4] range image of lidar-frame points (nearest row and column; -1 where empty).

    The inverse of the decoder for points on pixel directions; used to build test data and
    synthetic segments in Waymo's exact format.
    """
    H = len(inclinations)
    p = np.asarray(points_lidar, dtype=np.float64)
    rng = np.linalg.norm(p, axis=1)
    incl = np.arcsin(np.clip(p[:, 2] / np.maximum(rng, 1e-12), -1, 1))
    az = np.arctan2(p[:, 1], p[:, 0])
    az_correction = np.arctan2(lidar_to_vehicle[1, 0], lidar_to_vehicle[0, 0])
    ratio = ((az + az_correction) / np.pi + 1.0) / 2.0  # in (0, 1]
    col = np.mod(np.round(width - ratio * width - 0.5).astype(int), width)
    row = np.argmin(np.abs(incl[:, None] - inclinations[None, :]), axis=1)
    image = np.full((H, width, 4), -1.0, dtype=np.float32)
    image[..., 1:] = 0.0
    image[row, col, 0] = rng
    image[row, col, 1] = 0.0 if intensity is None else intensity
    return image
