"""Pieces of one long vehicle folded into it, once its box is complete.

Lidar motion clusters each sweep, and parts of one object merge only where they come within
``merge_distance`` of each other in every shared sweep (``lidar_motion.merge_parts``). A long
vehicle breaks that: an articulated lorry's cab stands apart from its trailer, and the lidar sees
a long flank only in pieces. The cab then becomes an instance of its own that moves with the
trailer: a false positive at every frame, and Gaussians that move on their own. A following car
also moves with a lorry, so nearness and a shared velocity cannot decide it; the completed box
can. After the amodal completion (:mod:`idsplat_ns.instances.amodal_centre`) the long vehicle's
box spans its whole length, and an instance whose origin stays inside that box, moving with it,
is a part of it: its canonical points join the long vehicle's and it stops being an instance.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks
from idsplat_ns.ranges import AT_LEAST_ONE, NON_NEGATIVE, UNIT, bounded

BOXES_KEY = "amodal_box"
"""``InstanceTracks.metadata`` key of the completed boxes: instance ID -> [length, width, forward x,
forward y] in metres and the canonical frame (written by ``amodal_centre.complete_centres``)."""


@dataclass(frozen=True)
class ContainedPartsConfig:
    """Which instances are parts of a long vehicle (see the module docstring)."""

    enabled: bool = True
    """False keeps every instance that lidar motion and registration made."""
    min_box_length: float = bounded(7.0, NON_NEGATIVE)
    """Metres: only a box at least this long (a truck, a bus, a lorry) takes parts."""
    margin: float = bounded(0.5, NON_NEGATIVE)
    """Metres around the box within which the middle of a part's points counts as inside."""
    min_inside_fraction: float = bounded(0.8, UNIT)
    """Share of the part's measured frames (shared with the vehicle) with its points' middle inside the box."""
    min_shared_frames: int = bounded(3, AT_LEAST_ONE)
    """Measured frames of the part at which the vehicle is posed too, at least."""


def points_centre_in_box(part: InstanceTrack, vehicle: InstanceTrack, box: np.ndarray,
                         frames: np.ndarray) -> np.ndarray:  # box [4], frames [K] -> [K, 2]
    """Along and across the box's length (metres from its centre, the vehicle's canonical origin):
    the middle of the part's points at ``frames``. Their middle, not the part's origin: a piece
    completed as a vehicle of its own has its origin pushed away from the sensor by half a
    typical length, beyond the long vehicle it belongs to."""
    middle = np.median(part.canonical_points, axis=0)
    world = np.einsum("kij,j->ki", part.poses[frames, :3, :3], middle) + part.poses[frames, :3, 3]
    R, t = vehicle.poses[frames, :3, :3], vehicle.poses[frames, :3, 3]
    local = np.einsum("kji,kj->ki", R, world - t)  # R^T (x - t_vehicle)
    forward = np.array([box[2], box[3], 0.0]) / max(float(np.hypot(box[2], box[3])), 1e-12)
    side = np.array([-forward[1], forward[0], 0.0])
    return np.stack([local @ forward, local @ side], axis=-1)


def _measured(inst: InstanceTrack) -> np.ndarray:
    return inst.measured_valid if inst.measured_valid is not None else inst.valid


def part_of(part: InstanceTrack, vehicle: InstanceTrack, box: np.ndarray, config: ContainedPartsConfig) -> bool:
    """Whether ``part`` stays inside ``vehicle``'s completed ``box`` (see the config)."""
    frames = np.flatnonzero(_measured(part) & vehicle.valid)
    if len(frames) < config.min_shared_frames or len(frames) < 0.5 * _measured(part).sum():
        return False
    offset = np.abs(points_centre_in_box(part, vehicle, box, frames))
    inside = (offset[:, 0] <= 0.5 * box[0] + config.margin) & (offset[:, 1] <= 0.5 * box[1] + config.margin)
    return bool(inside.mean() >= config.min_inside_fraction)


def _optional_concat(a: Optional[np.ndarray], b: Optional[np.ndarray]) -> Optional[np.ndarray]:
    return None if a is None or b is None else np.concatenate([a, b])


def fold_in(vehicle: InstanceTrack, part: InstanceTrack) -> InstanceTrack:
    """``vehicle`` with ``part``'s canonical points moved into its canonical frame (at the shared
    measured frame where the part has the most points) and its point counts added."""
    shared = np.flatnonzero(_measured(part) & vehicle.valid)
    f = int(shared[np.argmax(part.point_counts[shared])])
    T = np.linalg.inv(vehicle.poses[f]) @ part.poses[f]
    points = part.canonical_points @ T[:3, :3].T + T[:3, 3]
    counts = vehicle.point_counts + np.where(vehicle.valid, part.point_counts, 0)
    return replace(vehicle, canonical_points=np.concatenate([vehicle.canonical_points, points]),
                   canonical_colors=_optional_concat(vehicle.canonical_colors, part.canonical_colors),
                   point_frames=_optional_concat(vehicle.point_frames, part.point_frames),
                   point_times=_optional_concat(vehicle.point_times, part.point_times),
                   point_counts=counts)


def absorb_contained_parts(tracks: InstanceTracks, config: ContainedPartsConfig = ContainedPartsConfig()) -> InstanceTracks:
    """A copy of ``tracks`` in which each dynamic instance that is a part of a long vehicle (the
    config) is folded into it; ``metadata["folded_parts"]`` maps each part's ID to its vehicle's."""
    boxes = {int(k): np.asarray(v, np.float64) for k, v in tracks.metadata.get(BOXES_KEY, {}).items()}
    if not config.enabled or not boxes:
        return tracks
    by_id = {int(i.instance_id): i for i in tracks.instances}
    vehicles = sorted((i for i in boxes if i in by_id and boxes[i][0] >= config.min_box_length),
                      key=lambda i: -len(by_id[i].canonical_points))
    folded: dict[int, int] = {}
    for v in vehicles:
        if v in folded:
            continue
        for p, part in list(by_id.items()):
            if p == v or p in folded or p in vehicles and len(part.canonical_points) >= len(by_id[v].canonical_points):
                continue
            if part_of(part, by_id[v], boxes[v], config):
                by_id[v] = fold_in(by_id[v], part)
                folded[p] = v
    if not folded:
        return tracks
    kept = [by_id[int(i.instance_id)] for i in tracks.instances if int(i.instance_id) not in folded]
    return replace(tracks, instances=kept, metadata={**tracks.metadata, "folded_parts": {str(p): v for p, v in folded.items()}})
