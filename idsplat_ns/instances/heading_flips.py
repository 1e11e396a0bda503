"""Heading errors of registered poses, found from the direction of travel (ours, not the paper's).

A far vehicle gives a few dozen lidar points on one face. Its front and rear faces are both
roughly planar and as wide as the car, so feature-poor RANSAC registration can align the observed
face with the opposite face of the canonical point set: the pose is then turned by about 180°
about the vertical axis through the vehicle. A few points of a front face can also land on a side
of the canonical set (a quarter turn), and once such a frame's points join the canonical set, the
next sparse frames register to them and inherit the error. Fitness cannot tell these apart, but
the motion can: a vehicle drives along its own axis. For a moving instance, the offset between
the direction of travel and the registered yaw is the same at every frame (the CT smoother's
"shared rotation"); a measurement whose offset is far from the instance's common offset is turned
by the difference, refined by ICP, and kept only if it then fits.

On the synthetic street (small preset), seed 0: a pickup 40 m away making a 90° turn had 5 of its
15 registrations flipped; the CT smoother followed them and left it 5-7 m from the truth over half
its track. Seed 4: a car approaching from 45 m had its 10 far frames registered a quarter turn off
the canonical (near) frame, and the smoother dropped the near frames instead.

The direction of travel at a frame is the mean direction towards several neighbours in time, so
that one misplaced measurement (a car entering the view, registered 3.5 m ahead of itself) does
not reverse it and make its correct neighbour look flipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from idsplat_ns.data.geometry import make_pose, rot_z, wrap_angle, yaw_of
from idsplat_ns.ranges import UNIT, bounded


@dataclass(frozen=True)
class HeadingFlipConfig:
    """When a registered pose's heading counts as wrong (see the module docstring)."""

    enabled: bool = True
    """Detect and correct heading errors (False: the paper's registration output, unchanged)."""
    min_displacement: float = 0.5
    """Metres: the direction of travel at a frame is taken towards measurements at least this far
    away, so that position noise does not swamp it."""
    max_time_gap: float = 2.0
    """Seconds: only measurements this close in time give a direction of travel."""
    neighbours: int = 4
    """The direction of travel at a frame is the mean of the unit directions towards (or from) its
    this many nearest-in-time measurements (1: the nearest only)."""
    min_agreement: float = bounded(0.5, UNIT)
    """No direction of travel where the mean of those unit directions is shorter than this (they
    disagree: the frame or its neighbours are misplaced)."""
    agree_angle: float = math.radians(45.0)
    """A frame whose offset is within this of the common offset agrees with it."""
    turn_angle: float = math.radians(60.0)
    """A frame whose offset is at least this far from the common offset is turned by the difference
    (about 180° for a front/back flip, 90° for a front/side confusion)."""
    snap_angle: float = math.radians(25.0)
    """A difference this close to a multiple of 90° is taken as that multiple: confusions come from
    the box's symmetries, and the direction of travel is noisier than the registered yaw."""
    min_track_displacement: float = 1.0
    """Metres: instances that move less than this (the paper's static threshold) are left alone."""
    skip_stationary: bool = True
    """Instances whose lidar points stay in place in the world (the world-overlap test of
    static_conversion.py, with its defaults) are left alone too: a parked car has no direction of
    travel, and the "motion" of its slid registrations is not one."""


def travel_directions(
    times: np.ndarray,  # [T] seconds
    positions: np.ndarray,  # [T, 3] world
    valid: np.ndarray,  # [T] bool
    min_displacement: float,
    max_time_gap: float,
    neighbours: int,
    min_agreement: float,
) -> np.ndarray:
    """[T] world angle (rad) of the direction of travel at each valid frame, NaN where none: the
    mean unit direction (earlier to later) between the frame and its ``neighbours``
    closest-in-time valid frames at least ``min_displacement`` away in xy, where those directions
    agree (mean length at least ``min_agreement``)."""
    out = np.full(len(times), np.nan)
    idx = np.flatnonzero(valid)
    for k in idx:
        others = idx[idx != k]
        if len(others) == 0:
            continue
        d = positions[others, :2] - positions[k, :2]
        dt = times[others] - times[k]
        dist = np.linalg.norm(d, axis=1)
        ok = np.flatnonzero((dist >= min_displacement) & (np.abs(dt) <= max_time_gap))
        if len(ok) == 0:
            continue
        near = ok[np.argsort(np.abs(dt[ok]), kind="stable")[:neighbours]]
        unit = d[near] / dist[near, None] * np.sign(dt[near])[:, None]  # later minus earlier
        mean = unit.mean(0)
        if np.linalg.norm(mean) >= min_agreement:
            out[k] = math.atan2(mean[1], mean[0])
    return out


def heading_errors(
    times: np.ndarray,  # [T] seconds
    poses: np.ndarray,  # [T, 4, 4] canonical -> world
    valid: np.ndarray,  # [T] bool
    weights: np.ndarray,  # [T] trust of each measurement (e.g. its lidar point count)
    config: HeadingFlipConfig,
) -> np.ndarray:
    """[T] angle (rad) to add to each measurement's yaw, NaN where it is not wrong (agrees with
    the motion, has no direction of travel, or is not valid).

    The common offset (direction of travel minus yaw) is the candidate with the largest summed
    weight of agreeing frames; the canonical frame's own registration has the most points, so a
    minority of wrong headings cannot outvote it.
    """
    out = np.full(len(times), np.nan)
    direction = travel_directions(times, poses[:, :3, 3], valid, config.min_displacement, config.max_time_gap,
                                  config.neighbours, config.min_agreement)
    has = np.isfinite(direction)
    if has.sum() < 2:
        return out
    offset = wrap_angle(direction[has] - yaw_of(poses[has]))
    w = np.asarray(weights, np.float64)[has]
    support = [(w * (np.abs(wrap_angle(offset - o)) <= config.agree_angle)).sum() for o in offset]
    common = offset[int(np.argmax(support))]
    error = wrap_angle(offset - common)
    quarter = np.round(error / (math.pi / 2)) * (math.pi / 2)
    error = np.where(np.abs(error - quarter) <= config.snap_angle, quarter, error)
    wrong = np.abs(error) >= config.turn_angle
    out[np.flatnonzero(has)[wrong]] = error[wrong]
    return out


def turn_about(pose: np.ndarray, centre: np.ndarray, angle: float) -> np.ndarray:  # pose: [4, 4], centre: [3] canonical
    """``pose`` composed with a turn by ``angle`` (rad, counter-clockwise seen from above) about the
    canonical vertical axis through ``centre``: its world yaw grows by ``angle`` for an upright pose."""
    c = np.array([centre[0], centre[1], 0.0])
    return pose @ make_pose(np.eye(3), c) @ make_pose(rot_z(angle), np.zeros(3)) @ make_pose(np.eye(3), -c)


def canonical_box_centre(points: np.ndarray) -> np.ndarray:  # [N, 3] canonical -> [3]
    return 0.5 * (points.min(0) + points.max(0))
