"""Minimal reader of a Waymo Open Motion ``Scenario`` TFRecord for tests (no TensorFlow, no .proto).

Protobuf wire format, only the fields the smoothing tests need:
Scenario: timestamps_seconds = 1 (repeated double), tracks = 2 (Track).
Track: id = 1, object_type = 2 (1 = vehicle), states = 3 (ObjectState).
ObjectState: center_x/y/z = 2/3/4 (double), length/width/height = 5/6/7 (float),
heading = 8 (float), velocity_x/y = 9/10 (float), valid = 11 (bool).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from idsplat_ns.data.waymo.range_image import read_varint

VEHICLE = 1


@dataclass
class MotionTrack:
    """One object's states over the scenario's steps."""

    track_id: int
    object_type: int
    center: np.ndarray  # [T, 3] metres
    heading: np.ndarray  # [T] radians
    velocity: np.ndarray  # [T, 2] m/s
    valid: np.ndarray  # [T] bool


def _fields(buf: bytes):
    """Yield ``(field_number, wire_type, value)``; value is int, bytes (length-delimited) or raw 4/8 bytes."""
    pos = 0
    while pos < len(buf):
        key, pos = read_varint(buf, pos)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = read_varint(buf, pos)
        elif wire == 1:
            value, pos = buf[pos : pos + 8], pos + 8
        elif wire == 2:
            n, pos = read_varint(buf, pos)
            value, pos = buf[pos : pos + n], pos + n
        elif wire == 5:
            value, pos = buf[pos : pos + 4], pos + 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
        yield field, wire, value


def _state(buf: bytes) -> tuple[list[float], float, list[float], bool]:
    center, heading, vel, valid = [0.0, 0.0, 0.0], 0.0, [0.0, 0.0], False
    for field, _, value in _fields(buf):
        if field in (2, 3, 4):
            center[field - 2] = struct.unpack("<d", value)[0]
        elif field == 8:
            heading = struct.unpack("<f", value)[0]
        elif field in (9, 10):
            vel[field - 9] = struct.unpack("<f", value)[0]
        elif field == 11:
            valid = bool(value)
    return center, heading, vel, valid


def _track(buf: bytes) -> MotionTrack:
    track_id, object_type, states = 0, 0, []
    for field, _, value in _fields(buf):
        if field == 1:
            track_id = value
        elif field == 2:
            object_type = value
        elif field == 3:
            states.append(_state(value))
    return MotionTrack(
        track_id=track_id,
        object_type=object_type,
        center=np.array([s[0] for s in states], dtype=np.float64).reshape(-1, 3),
        heading=np.array([s[1] for s in states], dtype=np.float64),
        velocity=np.array([s[2] for s in states], dtype=np.float64).reshape(-1, 2),
        valid=np.array([s[3] for s in states], dtype=bool),
    )


def read_scenario(path: Path) -> tuple[np.ndarray, list[MotionTrack]]:
    """Timestamps [T] (s) and tracks of the first record of a Scenario TFRecord."""
    data = path.read_bytes()
    (length,) = struct.unpack("<Q", data[:8])
    record = data[12 : 12 + length]  # skip the length and its masked CRC
    times: list[float] = []
    tracks: list[MotionTrack] = []
    for field, wire, value in _fields(record):
        if field == 1 and wire == 2:  # packed doubles
            times.extend(struct.unpack(f"<{len(value) // 8}d", value))
        elif field == 1 and wire == 1:
            times.append(struct.unpack("<d", value)[0])
        elif field == 2:
            tracks.append(_track(value))
    return np.array(times), tracks
