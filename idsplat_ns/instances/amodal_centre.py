"""Amodal centres: move an instance's canonical origin to the middle of the whole vehicle, not of
the part the lidar saw.

The paper's canonical origin is the middle of the box around the densest view (Sec. 3.3). A car
followed from behind shows only its rear: the origin then sits half a car length (about 2 m) from
the vehicle's centre, and a bus seen from the front sits 5-6 m off. Rendering does not care
(the origin is a choice of frame), but tracking does: positions are compared with annotated box
centres, and such offsets turn every frame into a false positive plus a false negative at the
paper's 2 m gate (the paper names "constant offsets ... due to partial point clouds" as a source
of its tracking errors).

The completion (ours, not in the paper): along the direction of travel (from the CT smoother's
shared rotation) and across it, when the merged canonical points are shorter than a typical
vehicle of the instance's class, the visible face is the one towards the sensor, so the hidden
body extends away from it: the centre is put half a typical length behind the visible face.
Where the points already span a typical size, or the sensor was beside that face, the middle of
the points is kept. With the lidar ground under the instance, the centre's height is midway
between the ground and the highest points (a road user stands on the ground), and a long vehicle
whose roof stands higher than a bus's is completed to an articulated lorry's length: seen end-on
for a whole drive, a lorry's length is never measured, and a bus length puts its centre 2.3 m
short (docs/reports/2026-11-27-amodal-height.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from collections.abc import Callable
from typing import Optional

import numpy as np

from idsplat_ns.instances.contained_parts import BOXES_KEY, ContainedPartsConfig
from idsplat_ns.instances.registration import frame_surface_normals
from idsplat_ns.instances.tracks import InstanceTracks
from idsplat_ns.ranges import Range, bounded

# Typical (length, width) in metres per class keyword; the first keyword found in the label wins.
DEFAULT_CLASS_SIZES: tuple[tuple[str, float, float], ...] = (
    ("bus", 12.0, 2.55),
    ("train", 15.0, 3.0),
    ("trailer", 10.0, 2.5),
    ("pickup", 5.5, 2.0),
    ("truck", 7.0, 2.4),
    ("van", 5.0, 2.0),
    ("car", 4.5, 1.85),
    ("vehicle", 4.5, 1.85),
    ("motorcycle", 2.2, 0.8),
    ("bicycle", 1.8, 0.6),
    ("cyclist", 1.8, 0.6),
    ("pedestrian", 0.6, 0.6),
    ("human", 0.6, 0.6),
    ("person", 0.6, 0.6),
)


@dataclass(frozen=True)
class AmodalCentreConfig:
    """Amodal completion of the canonical origin (see the module docstring)."""

    enabled: bool = True
    """False keeps the paper's origin (middle of the densest view's box)."""
    class_sizes: tuple[tuple[str, float, float], ...] = field(default_factory=lambda: DEFAULT_CLASS_SIZES)
    """(label keyword, typical length, typical width) in metres; labels matching none are left as they are."""
    trim: float = bounded(0.02, Range(0, 0.5, high_open=True))
    """Fraction of the points ignored at each end of each axis (stray points from mask bleeding)."""
    ground_contact: bool = True
    """Put the centre's height midway between the lidar ground under the instance and its highest
    points (a road user stands on the ground; the lidar misses a trailer's open underside or a
    body hidden behind parked cars). False: the middle of the points' heights."""
    tall_roof_height: Optional[float] = 3.5
    """Metres above the lidar ground: a long vehicle (label ``bus`` or ``truck``) whose roof stands
    higher is completed to ``tall_size`` (articulated lorries stand about 4 m high, buses and box
    trucks 3-3.5 m). None: the label's size whatever the height."""
    tall_size: tuple[float, float] = (16.5, 2.55)
    """(length, width) in metres of a long vehicle taller than ``tall_roof_height``: an articulated
    lorry (the EU's maximum length)."""
    parts: ContainedPartsConfig = field(default_factory=ContainedPartsConfig)
    """Instances inside a long vehicle's completed box, moving with it, folded into it
    (:mod:`idsplat_ns.instances.contained_parts`)."""


def _is_long_vehicle(label: str) -> bool:
    low = label.lower()
    return "bus" in low or "truck" in low


def typical_size(label: str, class_sizes: tuple[tuple[str, float, float], ...] = DEFAULT_CLASS_SIZES) -> Optional[tuple[float, float]]:
    """(length, width) of the first class keyword contained in ``label`` (case-insensitive), or None."""
    low = label.lower()
    for key, length, width in class_sizes:
        if key in low:
            return length, width
    return None


def _completed_middle(coords: np.ndarray, sensor: float, size: float, trim: float) -> float:
    """Centre along one axis: coords [N] of the points, sensor coordinate, typical size."""
    lo, hi = np.quantile(coords, [trim, 1.0 - trim])
    if hi - lo >= size:
        return 0.5 * (lo + hi)
    if sensor >= hi:  # the visible face is the +axis one: the body extends to -axis
        return hi - 0.5 * size
    if sensor <= lo:
        return lo + 0.5 * size
    return 0.5 * (lo + hi)


def amodal_centre(
    points: np.ndarray,  # [N, 3] merged canonical points
    forward: np.ndarray,  # [3] direction of travel in the canonical frame
    sensor_positions: np.ndarray,  # [K, 3] the sensor in the canonical frame at the measured frames
    length: float,
    width: float,
    trim: float = 0.02,
    ground: Optional[float] = None,  # height of the ground in the canonical frame (None: unknown)
) -> np.ndarray:  # -> [3]
    """The completed centre of the module docstring, in the canonical frame; with ``ground`` its
    height is midway between the ground and the highest points."""
    f = np.array([forward[0], forward[1], 0.0], dtype=np.float64)
    if np.linalg.norm(f) < 1e-9:
        f = np.array([1.0, 0.0, 0.0])
    f /= np.linalg.norm(f)
    l = np.array([-f[1], f[0], 0.0])
    sensor = np.median(sensor_positions, axis=0)
    a = _completed_middle(points @ f, float(sensor @ f), length, trim)
    b = _completed_middle(points @ l, float(sensor @ l), width, trim)
    z_lo, z_hi = np.quantile(points[:, 2], [trim, 1.0 - trim])
    if ground is not None and np.isfinite(ground) and ground < z_hi:
        z_lo = min(z_lo, ground)
    return a * f + b * l + np.array([0.0, 0.0, 0.5 * (z_lo + z_hi)])


def shift_origin(
    points: np.ndarray,  # [N, 3] canonical points
    poses: np.ndarray,  # [F, 4, 4] canonical -> world
    centre: np.ndarray,  # [3] new origin in the old canonical frame
) -> tuple[np.ndarray, np.ndarray]:
    """Points and poses expressed about ``centre``: ``points - c`` and ``t + R c`` (every world
    position of every point is unchanged)."""
    moved = np.array(poses, dtype=np.float64, copy=True)
    moved[:, :3, 3] += np.einsum("fij,j->fi", moved[:, :3, :3], centre)
    return points - centre, moved


def travel_direction(poses: np.ndarray, valid: np.ndarray) -> Optional[np.ndarray]:  # poses [F, 4, 4], valid [F]
    """Mean direction of travel in the canonical frame (``sum R_t^T (t_t+1 - t_t)`` over
    consecutive valid steps), or None when the instance moves less than 0.5 m in total."""
    k = np.flatnonzero(valid)
    if len(k) < 2:
        return None
    steps = poses[k[1:], :3, 3] - poses[k[:-1], :3, 3]  # [S, 3] world
    local = np.einsum("sji,sj->si", poses[k[:-1], :3, :3], steps)  # R^T step
    if np.linalg.norm(steps, axis=1).sum() < 0.5:
        return None
    # Steps can point either way along the axis (a sign flip is the same box): align them first.
    ref = local[np.argmax(np.linalg.norm(local, axis=1))]
    signs = np.where(local @ ref < 0, -1.0, 1.0)
    total = (local * signs[:, None]).sum(0)
    return total / max(np.linalg.norm(total), 1e-12)


def box_heading(
    points: np.ndarray,  # [N, 3] canonical points
    forward: np.ndarray,  # [3] a rough direction of travel in the canonical frame
    point_frames: Optional[np.ndarray] = None,  # [N] the frame of each point (normals per frame)
    k: int = 12,
) -> np.ndarray:  # -> [3] unit, horizontal
    """The axis of the vehicle's box nearest to ``forward``. The mean direction of travel of the
    canonical origin is not the heading on a turn: an origin off the rear axle also moves
    sideways (on the synthetic street's 6 m turn, 20 degrees off). A box's faces are at right
    angles, so their horizontal normals agree on its orientation modulo 90 degrees (the circular
    mean of four times their angles); of its four axes, the one nearest ``forward`` is taken.
    ``forward`` itself where the points show no vertical faces."""
    f = np.array([forward[0], forward[1], 0.0])
    f /= max(np.linalg.norm(f), 1e-12)
    horizontal = frame_surface_normals(points, point_frames, k)[:, :2]
    weight = np.einsum("ni,ni->n", horizontal, horizontal)  # cos^2 of the face's tilt; 0 without a normal
    if weight.sum() < 1e-6:
        return f
    angle = 4.0 * np.arctan2(horizontal[:, 1], horizontal[:, 0])
    box = 0.25 * np.arctan2(float(np.sum(weight * np.sin(angle))), float(np.sum(weight * np.cos(angle))))
    axes = [np.array([np.cos(box + q), np.sin(box + q), 0.0]) for q in 0.5 * np.pi * np.arange(4)]
    return max(axes, key=lambda a: float(a @ f))


def sensors_in_canonical(
    poses: np.ndarray,  # [F, 4, 4] canonical -> world
    sensor_positions: np.ndarray,  # [F, 3] world
    frames: np.ndarray,  # [K] frame indices
) -> np.ndarray:  # -> [K, 3]
    """The sensor at ``frames`` in the instance's canonical frame: ``R^T (s - t)``."""
    k = np.asarray(frames)
    R, t = poses[k, :3, :3], poses[k, :3, 3]
    return np.einsum("kji,kj->ki", R, np.asarray(sensor_positions, np.float64)[k] - t)


def ground_in_canonical(
    poses: np.ndarray,  # [F, 4, 4] canonical -> world
    frames: np.ndarray,  # [K] frame indices
    ground_heights: Callable[[np.ndarray], np.ndarray],  # world xy [M, 2] -> ground heights [M] (NaN: unknown)
) -> Optional[float]:
    """Height of the ground under the canonical origin in the canonical frame (its z axis taken as
    the world's up: a road user is turned about the vertical): the median over ``frames`` of
    ``ground(t_xy) - t_z``; None where the ground is unknown at every frame."""
    t = poses[np.asarray(frames), :3, 3]
    below = ground_heights(t[:, :2]) - t[:, 2]
    below = below[np.isfinite(below)]
    return float(np.median(below)) if len(below) else None


def complete_centres(
    tracks: InstanceTracks,
    sensor_positions: np.ndarray,  # [F, 3] the (main lidar) sensor in the world at each of the tracks' frames
    config: AmodalCentreConfig = AmodalCentreConfig(),
    ground_heights: Optional[Callable[[np.ndarray], np.ndarray]] = None,  # world xy [M, 2] -> [M], NaN: unknown
) -> InstanceTracks:
    """A copy of ``tracks`` whose dynamic instances have amodal canonical origins. ``ground_heights``
    (the lidar ground, ``GroundSurface.heights_at``) serves ``ground_contact`` and ``tall_roof_height``."""
    if not config.enabled:
        return tracks
    out, moved, boxes = [], {}, {}
    for inst in tracks.instances:
        size = typical_size(inst.label, config.class_sizes)
        measured = inst.measured_valid if inst.measured_valid is not None else inst.valid
        forward = travel_direction(inst.poses, inst.valid)
        if size is None or forward is None or not measured.any() or len(inst.canonical_points) < 3:
            out.append(inst)
            continue
        ground = None
        if ground_heights is not None and (config.ground_contact or config.tall_roof_height is not None):
            ground = ground_in_canonical(inst.poses, np.flatnonzero(measured), ground_heights)
        if config.tall_roof_height is not None and ground is not None and _is_long_vehicle(inst.label):
            roof = float(np.quantile(inst.canonical_points[:, 2], 1.0 - config.trim)) - ground
            if roof > config.tall_roof_height:
                size = config.tall_size
        forward = box_heading(inst.canonical_points, forward, inst.point_frames)
        sensors = sensors_in_canonical(inst.poses, sensor_positions, np.flatnonzero(measured))
        c = amodal_centre(inst.canonical_points, forward, sensors, size[0], size[1], config.trim,
                          ground if config.ground_contact else None)
        points, poses = shift_origin(inst.canonical_points, inst.poses, c)
        moved[int(inst.instance_id)] = [float(x) for x in c]
        boxes[int(inst.instance_id)] = completed_box(points, forward, size, config.trim)
        out.append(replace(inst, canonical_points=points, poses=poses))
    return replace(tracks, instances=out, metadata={**tracks.metadata, "amodal_centre_shift": moved, BOXES_KEY: boxes})


def completed_box(points: np.ndarray, forward: np.ndarray, size: tuple[float, float], trim: float) -> list[float]:
    """[length, width, forward x, forward y] of the completed box about the canonical origin: the
    typical ``size``, or the points' (trimmed) extent where they span more."""
    f = np.array([forward[0], forward[1]]) / max(float(np.hypot(forward[0], forward[1])), 1e-12)
    xy = points[:, :2]
    spans = [float(np.subtract(*np.quantile(xy @ axis, [1.0 - trim, trim]))) for axis in (f, np.array([-f[1], f[0]]))]
    return [max(size[0], spans[0]), max(size[1], spans[1]), float(f[0]), float(f[1])]
