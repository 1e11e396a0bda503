"""Linking an instance's split segments back into one trajectory through the vehicle's box.

When the frames of one mask instance do not all register together (a turning car seen from the
front while far, then from its side and rear when near, shares no surface between the two
views), registration keeps the frames that do register as the instance and makes the rest a
segment of its own (trajectory_estimation.py, ``min_segment_frames``). The two are the same
vehicle (the 2D tracker gave them one mask ID), each with its own canonical frame, and the
vehicle vanishes between them. Rendering then learns two half cars with a gap between, and
tracking counts an identity switch.

The link (ours, not in the paper): in each part, the vehicle's box frame is known without any
shared surface: its centre from the amodal completion of that part's points (amodal_centre.py:
the visible faces, the sensor positions and the class's typical size), its forward axis from the
part's direction of travel. Mapping one box frame onto the other gives the transform between the
two canonical frames. The link is kept only when the motion across the gap is plausible (the
speed across it close to the speeds on both sides); the CT smoother then fills the gap.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from idsplat_ns.data.geometry import invert_pose, transform_points
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.amodal_centre import (
    amodal_centre,
    box_heading,
    sensors_in_canonical,
    travel_direction,
    typical_size,
)
from idsplat_ns.instances.tracks import InstanceTrack, fill_invalid_poses


@dataclass(frozen=True)
class SegmentLinkConfig:
    """When a split segment is linked back to its instance (see the module docstring)."""

    enabled: bool = True
    """False keeps split segments as instances of their own."""
    max_gap: float = 2.0
    """Seconds: segments further apart in time than this stay separate."""
    speed_ratio: float = 1.5
    """The speed across the gap must be within this factor of the speeds on both sides..."""
    speed_slack: float = 1.0
    """...give or take this many metres per second (slow vehicles, noisy short parts)."""
    max_intruders: int = 3
    """Where the parts interleave in time, the fewest frames (of either part) whose removal puts
    one part wholly before the other are dropped to link them, up to this many: a few frames among
    the other part's consistent ones are the misregistered ones (seed 0: one far frame registered
    onto the near canonical points a quarter turn and 2.7 m off; seed 7: three far frames 1.2 m off
    with the right rotation, between seven of the segment's within 0.4 m; seed 8: the instance's
    three first frames a quarter turn off, before the whole segment). More: no link."""

    def __post_init__(self) -> None:
        if self.speed_ratio < 1.0:
            raise IDSplatError(f"link-segments.speed-ratio must be >= 1 (a factor either way), got {self.speed_ratio}")
        if self.max_gap < 0 or self.speed_slack < 0 or self.max_intruders < 0:
            raise IDSplatError("link-segments.max-gap, speed-slack and max-intruders must be >= 0; "
                               f"got {self.max_gap}, {self.speed_slack}, {self.max_intruders}")


def box_frame(
    track: InstanceTrack,
    sensor_positions: np.ndarray,  # [F, 3] world
) -> Optional[np.ndarray]:  # -> [4, 4] box frame -> canonical
    """The vehicle's box frame in ``track``'s canonical frame: origin at the amodal centre of its
    points, x along its direction of travel, z up. None when the class has no typical size or the
    track does not move (no direction of travel)."""
    size = typical_size(track.label)
    forward = travel_direction(track.poses, track.valid)
    if size is None or forward is None or len(track.canonical_points) < 3:
        return None
    forward = box_heading(track.canonical_points, forward, track.point_frames)
    sensors = sensors_in_canonical(track.poses, sensor_positions, np.flatnonzero(track.valid))
    centre = amodal_centre(track.canonical_points, forward, sensors, size[0], size[1])
    f = np.array([forward[0], forward[1], 0.0])
    f /= max(np.linalg.norm(f), 1e-12)
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = f, np.cross([0.0, 0.0, 1.0], f), [0.0, 0.0, 1.0], centre
    return out


def _speeds(centres: np.ndarray, times: np.ndarray) -> np.ndarray:  # [K, 3], [K] -> [K - 1] m/s
    return np.linalg.norm(np.diff(centres, axis=0), axis=1) / np.maximum(np.diff(times), 1e-6)


def _drop_frames(track: InstanceTrack, frames: np.ndarray) -> InstanceTrack:  # frames: [K] indices
    keep = np.ones(len(track.valid), bool)
    keep[frames] = False
    out = track.keep_points_of_frames(keep, min_points=0)
    return replace(out, valid=track.valid & keep)


def _without_intruders(
    track: InstanceTrack, segment: InstanceTrack, max_intruders: int
) -> Optional[tuple[InstanceTrack, InstanceTrack]]:
    """Both parts without the fewest frames whose removal puts one part wholly before the other in
    time, or None when that takes more than ``max_intruders`` frames or half of a part's frames
    (the parts then truly interleave). The frames dropped are the
    misregistered ones: a lone far frame registered into the other part's span, or the first few
    frames of a part registered a quarter turn off ahead of the other (seed 8: three such frames
    before the segment made the segment sit inside the instance's span)."""
    a, b = np.flatnonzero(track.valid), np.flatnonzero(segment.valid)
    if len(a) == 0 or len(b) == 0:
        return None
    majority = lambda dropped, part: len(dropped) > 0 and 2 * len(dropped) >= len(part)
    best = None  # (dropped count, frames dropped from track, frames dropped from segment)
    # Every split between two frames, with either part first (parts apart already cost nothing).
    for cut in np.union1d(a, b) + 0.5:
        for track_first in (True, False):
            drop_a = a[a > cut] if track_first else a[a < cut]
            drop_b = b[b < cut] if track_first else b[b > cut]
            if majority(drop_a, a) or majority(drop_b, b):
                continue  # the parts truly interleave there
            cost = len(drop_a) + len(drop_b)
            if best is None or cost < best[0]:
                best = (cost, drop_a, drop_b)
    if best is None or best[0] > max_intruders:
        return None
    _, drop_a, drop_b = best
    return (_drop_frames(track, drop_a) if len(drop_a) else track,
            _drop_frames(segment, drop_b) if len(drop_b) else segment)


def link_segment(
    track: InstanceTrack,
    segment: InstanceTrack,
    sensor_positions: np.ndarray,  # [F, 3] world
    times: np.ndarray,  # [F] seconds
    config: SegmentLinkConfig = SegmentLinkConfig(),
) -> Optional[InstanceTrack]:
    """``track`` with ``segment``'s frames and points added in its canonical frame, or None when
    they cannot be linked: no box frame for either, parts that interleave in time (beyond
    ``config.max_intruders`` lone frames, which are dropped), a gap longer than
    ``config.max_gap`` or a speed across it unlike the speeds on both sides."""
    parts = _without_intruders(track, segment, config.max_intruders)
    if parts is None:
        return None
    track, segment = parts
    a, b = np.flatnonzero(track.valid), np.flatnonzero(segment.valid)
    if len(a) < 2 or len(b) < 2:
        return None
    box_t, box_s = box_frame(track, sensor_positions), box_frame(segment, sensor_positions)
    if box_t is None or box_s is None:
        return None
    to_track = box_t @ invert_pose(box_s)  # segment canonical -> track canonical
    seg_poses = segment.poses @ invert_pose(to_track)  # [F, 4, 4] track canonical -> world
    # The box centre in the world on both sides of the gap, and the speed across it.
    centre = box_t[:3, 3]
    early, late = (a, b) if a[-1] < b[0] else (b, a)
    pose_of = lambda f: track.poses[f] if track.valid[f] else seg_poses[f]
    c_early = np.stack([transform_points(pose_of(f), centre[None])[0] for f in early[-3:]])
    c_late = np.stack([transform_points(pose_of(f), centre[None])[0] for f in late[:3]])
    gap = times[late[0]] - times[early[-1]]
    if gap > config.max_gap or gap <= 0:
        return None
    across = np.linalg.norm(c_late[0] - c_early[-1]) / gap
    sides = [float(np.mean(_speeds(c, times[f]))) for c, f in ((c_early, early[-3:]), (c_late, late[:3]))]
    if not (min(sides) / config.speed_ratio - config.speed_slack <= across
            <= max(sides) * config.speed_ratio + config.speed_slack):
        return None
    poses = np.where(segment.valid[:, None, None], seg_poses, track.poses)
    valid = track.valid | segment.valid
    points = np.concatenate([track.canonical_points, transform_points(to_track, segment.canonical_points)])
    colors = None
    if track.canonical_colors is not None and segment.canonical_colors is not None:
        colors = np.concatenate([track.canonical_colors, segment.canonical_colors])
    point_frames = point_times = None
    if track.point_frames is not None and segment.point_frames is not None:
        point_frames = np.concatenate([track.point_frames, segment.point_frames])
        if track.point_times is not None and segment.point_times is not None:
            point_times = np.concatenate([track.point_times, segment.point_times])
    return replace(
        track, canonical_points=points, canonical_colors=colors, poses=fill_invalid_poses(poses, valid), valid=valid,
        point_counts=np.maximum(track.point_counts, segment.point_counts),
        fitness=np.where(segment.valid, segment.fitness, track.fitness), point_frames=point_frames,
        point_times=point_times,
    )
