"""Planar trajectories of rigid objects in the street's local frame (metres, radians, seconds).

A trajectory maps times to a ground position and a heading: `pose(t) -> (xy [N, 2], heading [N])`.
The heading is the direction of the object's forward (+x) axis, counter-clockwise from local +x.
`height(t) -> [N]` is the height of the ground under the object (0 on the road; pedestrians on
the raised sidewalks have their own trajectory, `people.FootPath`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _unit(angle: np.ndarray | float) -> np.ndarray:
    """Unit vectors [..., 2] at the given angles."""
    angle = np.asarray(angle, dtype=np.float64)
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


@dataclass(frozen=True)
class Stationary:
    """An object that does not move (parked car)."""

    x: float
    """Local x of the footprint centre."""
    y: float
    """Local y of the footprint centre."""
    heading: float
    """Forward direction, radians from local +x."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position [N, 2] and heading [N] at times `t` [N]."""
        t = np.asarray(t, dtype=np.float64)
        xy = np.broadcast_to(np.array([self.x, self.y]), t.shape + (2,)).copy()
        return xy, np.full(t.shape, self.heading)

    def height(self, t: np.ndarray) -> np.ndarray:
        """Height [N] of the object's footprint above the road at times `t` [N]: on the road."""
        return np.zeros(np.shape(t))


@dataclass(frozen=True)
class Straight:
    """Constant velocity along a straight line."""

    x0: float
    """Local x at t = 0."""
    y0: float
    """Local y at t = 0."""
    heading: float
    """Direction of travel, radians from local +x."""
    speed: float
    """Speed, m/s."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position [N, 2] and heading [N] at times `t` [N]."""
        t = np.asarray(t, dtype=np.float64)
        xy = np.array([self.x0, self.y0]) + (self.speed * t)[..., None] * _unit(self.heading)
        return xy, np.full(t.shape, self.heading)

    def height(self, t: np.ndarray) -> np.ndarray:
        """Height [N] of the object's footprint above the road at times `t` [N]: on the road."""
        return np.zeros(np.shape(t))


@dataclass(frozen=True)
class StraightArcStraight:
    """A turn: a straight lead-in, a circular arc, a straight lead-out, driven at constant speed.

    Arc length along the path is `s(t) = s0 + speed * t`; before the start and after the end the
    first and last straight segments are extended, so every time has a pose.
    """

    start_x: float
    """Local x where the lead-in starts (s = 0)."""
    start_y: float
    """Local y where the lead-in starts."""
    start_heading: float
    """Heading along the lead-in, radians."""
    lead_in: float
    """Length of the lead-in, metres."""
    radius: float
    """Turn radius, metres."""
    turn_angle: float
    """Signed turn angle, radians (positive turns left, counter-clockwise)."""
    s0: float
    """Arc length reached at t = 0."""
    speed: float
    """Speed along the path, m/s."""

    @property
    def arc_length(self) -> float:
        """Length of the circular part, metres."""
        return abs(self.turn_angle) * self.radius

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position [N, 2] and heading [N] at times `t` [N]."""
        t = np.asarray(t, dtype=np.float64)
        s = self.s0 + self.speed * t
        sign = np.sign(self.turn_angle)
        h0 = self.start_heading
        a = np.array([self.start_x, self.start_y])
        b = a + self.lead_in * _unit(h0)  # start of the arc
        left0 = _unit(h0 + np.pi / 2)
        centre = b + sign * self.radius * left0
        h1 = h0 + self.turn_angle
        d = centre - sign * self.radius * _unit(h1 + np.pi / 2)  # end of the arc

        s_arc = np.clip(s - self.lead_in, 0.0, self.arc_length)
        heading = h0 + sign * s_arc / self.radius
        on_arc = centre - sign * self.radius * _unit(heading + np.pi / 2)
        before = a + s[..., None] * _unit(h0)
        after = d + (s - self.lead_in - self.arc_length)[..., None] * _unit(h1)
        xy = np.where(
            (s < self.lead_in)[..., None],
            before,
            np.where((s > self.lead_in + self.arc_length)[..., None], after, on_arc),
        )
        return xy, heading

    def height(self, t: np.ndarray) -> np.ndarray:
        """Height [N] of the object's footprint above the road at times `t` [N]: on the road."""
        return np.zeros(np.shape(t))


@dataclass(frozen=True, eq=False)
class PathMotion:
    """Motion along any planar path with a speed profile: lane changes, U-turns, turns, stop-and-go.

    The path is a polyline sampled densely (a few decimetres: headings change by well under a
    degree between samples); the distance travelled is tabulated over time. Before the first and
    after the last knot the object goes on at the end speeds, along the path's end directions, so
    every time has a pose. The heading is the path's direction, interpolated between segment
    midpoints (continuous, also while the object stands still).
    """

    path: np.ndarray  # [P, 2]
    """Local points along the path, in driving order."""
    times: np.ndarray  # [Q]
    """Increasing times (seconds) at which the distance travelled is known."""
    distance: np.ndarray  # [Q]
    """Distance along the path at `times`, metres (non-decreasing)."""

    def _lengths(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        seg = np.diff(self.path, axis=0)
        length = np.linalg.norm(seg, axis=1)
        cum = np.concatenate([[0.0], np.cumsum(length)])
        heading = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
        return cum, heading, seg / length[:, None]

    def distance_at(self, t: np.ndarray) -> np.ndarray:
        """Distance travelled along the path at times `t` [N] (extrapolated at the end speeds)."""
        t = np.asarray(t, dtype=np.float64)
        s = np.interp(t, self.times, self.distance)
        v0 = (self.distance[1] - self.distance[0]) / (self.times[1] - self.times[0])
        v1 = (self.distance[-1] - self.distance[-2]) / (self.times[-1] - self.times[-2])
        s = np.where(t < self.times[0], self.distance[0] + v0 * (t - self.times[0]), s)
        return np.where(t > self.times[-1], self.distance[-1] + v1 * (t - self.times[-1]), s)

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position [N, 2] and heading [N] at times `t` [N]."""
        cum, heading, unit = self._lengths()
        s = self.distance_at(t)
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(unit) - 1)
        xy = self.path[k] + (s - cum[k])[..., None] * unit[k]  # beyond the ends: along the end segments
        mids = 0.5 * (cum[:-1] + cum[1:])
        return xy, np.interp(s, mids, heading)

    def height(self, t: np.ndarray) -> np.ndarray:
        """Height [N] of the object's footprint above the road at times `t` [N]: on the road."""
        return np.zeros(np.shape(t))


Trajectory = Stationary | Straight | StraightArcStraight | PathMotion
