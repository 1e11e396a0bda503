"""Where the street's pedestrians and cyclists go, and the cuboids that hold their moving bodies.

- Pedestrian 0 crosses the road 12-22 m ahead of the ego's mid-sequence position (on the road at
  mid-sequence; close, so that the small images show it at 20-30 px); the others walk along the
  sidewalks, both sides, both directions, up to 30 m ahead of the ego.
- Cyclists ride near the right edge of a traffic lane, in its direction of travel, ahead of the ego.
- Speeds: walking 1.2-1.6 m/s, cycling 4-6 m/s.

Every placement is checked against the vehicles, the ego and the people already placed over the
whole sequence (footprints kept `CLEARANCE` apart); among random candidates the first clear one is
taken, or the one with the largest gap if none is clear (very long sequences).
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from idsplat_ns.data.synthetic.config import SyntheticConfig
from idsplat_ns.data.synthetic.people import CLEARANCE, EGO_HALF_SIZE, cyclist_parts, walker_parts
from idsplat_ns.data.synthetic.trajectories import Straight, Trajectory
from idsplat_ns.data.synthetic.shapes import BOX, CYLINDER, ELLIPSOID, Part, SceneObject, StreetLayout
from idsplat_ns.data.synthetic.vehicles import VEHICLE_SIZES

WALK_SPEED = (1.2, 1.6)
"""Range of walking speeds, m/s."""
CYCLE_SPEED = (4.0, 6.0)
"""Range of cycling speeds, m/s."""
CURB_RAMP = 0.3
"""Width (m) over which a walker's ground height follows the curb (a step, not a jump)."""


def ground_height(layout: StreetLayout, xy: np.ndarray) -> np.ndarray:
    """Height [N] of the walking surface at local points `xy` [N, 2]: the road or a raised sidewalk."""
    on_walk = np.abs(xy[:, 1]) - layout.road_half_width  # > 0 beyond the curb
    mouth = np.abs(xy[:, 0] - layout.side_street_x) - layout.side_street_half_width  # < 0 in the side street
    inside = np.where(xy[:, 1] > 0, np.minimum(on_walk, mouth), on_walk)
    w = np.clip(0.5 + inside / CURB_RAMP, 0.0, 1.0)
    return layout.curb_height * w * w * (3 - 2 * w)


@dataclass(frozen=True)
class FootPath(Straight):
    """A walk at constant velocity whose height follows the ground (down the curb, up the other)."""

    layout: StreetLayout = field(default_factory=StreetLayout)
    """Street whose sidewalks raise the walker."""

    def height(self, t: np.ndarray) -> np.ndarray:
        """Height [N] of the ground under the walker at times `t` [N]."""
        xy, _ = self.pose(np.asarray(t, float))
        return ground_height(self.layout, xy.reshape(-1, 2)).reshape(np.shape(t))


# -- cuboids -----------------------------------------------------------------------------------------


def part_half_extents(kind: int, size: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Half extents [N, 3] along the object axes of a part of `kind` with rotations [N, 3, 3].

    Exact for each kind (a turning cylinder's box is not its corners' box).
    """
    if kind == BOX:
        return np.abs(rotation) @ size
    if kind == ELLIPSOID:
        return np.sqrt((rotation**2) @ (size**2))
    if kind == CYLINDER:
        axis_k = rotation[..., 2]  # [N, 3] the cylinder's axis in object coordinates
        return size[2] * np.abs(axis_k) + size[0] * np.sqrt(np.clip(1.0 - axis_k**2, 0.0, 1.0))
    raise ValueError(f"no extents for part kind {kind}")


def enclosing_dimensions(parts: list[Part], period: float, samples: int = 96, margin: float = 0.03) -> tuple[float, float, float]:
    """(width, length, height) of a box centred on the origin in x and y, standing on z = 0, that holds
    every part over one `period` of its motion (sampled, plus `margin`)."""
    t = np.linspace(0.0, period, samples, endpoint=False)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for part in parts:
        if part.motion is None:
            centre, rot = part.center[None], part.rotation[None]
        else:
            centre, rot = part.motion.pose(t)
        ext = part_half_extents(part.kind, part.size, rot)
        lo, hi = np.minimum(lo, (centre - ext).min(0)), np.maximum(hi, (centre + ext).max(0))
    half_len = max(-lo[0], hi[0]) + margin
    half_wid = max(-lo[1], hi[1]) + margin
    return 2 * half_wid, 2 * half_len, hi[2] + margin


# -- placement ---------------------------------------------------------------------------------------


@dataclass
class _Obstacle:
    """A footprint over the check times: rectangles (vehicles, ego) or chains of discs (people)."""

    xy: np.ndarray  # [T, 2] centre
    heading: np.ndarray  # [T]
    half: tuple[float, float] | None = None  # rectangle half length, half width
    discs: np.ndarray | None = None  # [K] disc offsets along the heading (people)
    radius: float = 0.0  # disc radius


def _discs(traj: Trajectory, t: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Disc centres [T, K, 2] of a person's footprint."""
    xy, heading = traj.pose(t)
    fwd = np.stack([np.cos(heading), np.sin(heading)], -1)
    return xy[:, None, :] + offsets[None, :, None] * fwd[:, None, :]


def _gap(traj: Trajectory, offsets: np.ndarray, radius: float, t: np.ndarray, obstacles: list[_Obstacle]) -> float:
    """Smallest distance (m) between a person's discs and any obstacle over times `t` (negative: overlap)."""
    mine = _discs(traj, t, offsets)  # [T, K, 2]
    gap = np.inf
    for ob in obstacles:
        if ob.half is not None:  # distance from each disc centre to the rectangle, minus the radius
            c, s = np.cos(ob.heading)[:, None], np.sin(ob.heading)[:, None]
            d = mine - ob.xy[:, None, :]
            local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)
            outside = np.maximum(np.abs(local) - np.array(ob.half), 0.0)
            gap = min(gap, float((np.linalg.norm(outside, axis=-1) - radius).min()))
        else:
            theirs = ob.xy[:, None, :] + ob.discs[None, :, None] * np.stack([np.cos(ob.heading), np.sin(ob.heading)], -1)[:, None, :]
            d = np.linalg.norm(mine[:, :, None, :] - theirs[:, None, :, :], axis=-1)
            gap = min(gap, float((d - radius - ob.radius).min()))
    return gap


def _vehicle_obstacles(vehicles: list[SceneObject], ego: Straight, t: np.ndarray) -> list[_Obstacle]:
    out = []
    for v in vehicles:
        length, width, _ = VEHICLE_SIZES[v.label]
        xy, heading = v.trajectory.pose(t)
        out.append(_Obstacle(xy, heading, half=(length / 2, width / 2)))
    xy, heading = ego.pose(t)
    out.append(_Obstacle(xy, heading, half=EGO_HALF_SIZE))
    return out


def _pick(candidates: Iterable[Straight], offsets: np.ndarray, radius: float, t: np.ndarray,
          obstacles: list[_Obstacle]) -> Straight:
    """The first candidate trajectory that keeps `CLEARANCE`, else the one with the largest gap."""
    best, best_gap = None, -np.inf
    for traj in candidates:
        gap = _gap(traj, offsets, radius, t, obstacles)
        if gap >= CLEARANCE:
            return traj
        if gap > best_gap:
            best, best_gap = traj, gap
    return best


_WALKER = (np.zeros(1), 0.4)
"""Footprint of a walker: disc offsets along the heading and radius."""
_RIDER = (np.array([-0.55, 0.0, 0.55]), 0.4)
"""Footprint of a cyclist: three discs along the bicycle."""


def _crossing_candidates(rng: np.random.Generator, layout: StreetLayout, ego_x_mid: float, t_mid: float,
                         speed: float) -> Iterator[FootPath]:
    """Walks across the road ahead of the ego, on the road at mid-sequence (random order)."""
    x = ego_x_mid + rng.uniform(12.0, 22.0)
    direction = 1 if rng.random() < 0.5 else -1
    y_mid = rng.permutation(np.linspace(-2 * layout.lane_width, 2 * layout.lane_width, 29))
    for k, y in enumerate(y_mid):
        d = direction if k % 2 == 0 else -direction
        yield FootPath(x, y - d * speed * t_mid, d * np.pi / 2, speed, layout)


def _sidewalk_candidates(rng: np.random.Generator, layout: StreetLayout, ego_x_mid: float, t_mid: float,
                         side: int, speed: float, tries: int = 30) -> Iterator[FootPath]:
    """Walks along one sidewalk (clear of trees and poles near the curb), ahead of the ego at mid-sequence."""
    for _ in range(tries):
        y = side * (layout.road_half_width + rng.uniform(2.2, 3.3))
        heading = 0.0 if rng.random() < 0.5 else np.pi
        x_mid = ego_x_mid + rng.uniform(4.0, 30.0)
        yield FootPath(x_mid - np.cos(heading) * speed * t_mid, y, heading, speed, layout)


def _lane_candidates(rng: np.random.Generator, layout: StreetLayout, ego_x_mid: float, t_mid: float,
                     first_lane: int, speed: float, tries: int = 12) -> Iterator[Straight]:
    """Rides near the right edge of each lane in turn (oncoming outer, ego lane, fast lane, oncoming inner)."""
    lane = layout.lane_width
    lanes = [(1.5 * lane, np.pi), (-1.5 * lane, 0.0), (-0.5 * lane, 0.0), (0.5 * lane, np.pi)]
    for k in range(len(lanes)):
        centre, heading = lanes[(first_lane + k) % len(lanes)]
        y = centre - np.cos(heading) * 0.9  # right of the direction of travel
        for _ in range(tries):
            x_mid = ego_x_mid + rng.uniform(8.0, 32.0)
            yield Straight(x_mid - np.cos(heading) * speed * t_mid, y, heading, speed)


def _person(name: str, parts: list[Part], period: float, traj: Trajectory, instance_id: int, label: str,
            attributes: dict[str, str], rng: np.random.Generator) -> SceneObject:
    return SceneObject(
        name=name,
        parts=parts,
        trajectory=traj,
        instance_id=instance_id,
        label=label,
        moving=True,
        dimensions=enclosing_dimensions(parts, period),
        uuid=str(uuid.UUID(bytes=rng.bytes(16), version=4)),
        attributes=attributes,
    )


def place_people(rng: np.random.Generator, layout: StreetLayout, config: SyntheticConfig, ego: Straight,
                 vehicles: list[SceneObject], first_id: int) -> list[SceneObject]:
    """`config.num_pedestrians` walkers and `config.num_cyclists` riders, with instance ids from `first_id`."""
    t_mid = config.duration / 2
    t = np.linspace(-0.1, config.duration + 0.1, max(24, 4 * config.num_frames))  # sweeps reach 50 ms out
    obstacles = _vehicle_obstacles(vehicles, ego, t)
    ego_x_mid = float(ego.pose(np.array([t_mid]))[0][0, 0])
    people: list[SceneObject] = []
    first_side = 1 if rng.random() < 0.5 else -1
    for i in range(config.num_pedestrians):
        speed = rng.uniform(*WALK_SPEED)
        if i == 0:
            candidates = _crossing_candidates(rng, layout, ego_x_mid, t_mid, speed)
        else:
            side = first_side if i % 2 else -first_side
            candidates = _sidewalk_candidates(rng, layout, ego_x_mid, t_mid, side, speed)
        traj = _pick(candidates, *_WALKER, t, obstacles)
        parts, gait = walker_parts(rng, speed)
        name = "crossing_pedestrian" if i == 0 else f"pedestrian_{i}"
        people.append(_person(name, parts, 1.0 / gait.frequency, traj, first_id + len(people), "Pedestrian",
                              {"attributes.pedestrian_behavior": "Walking", "attributes.pedestrian_age": "Adult"}, rng))
        obstacles.append(_Obstacle(*traj.pose(t), discs=_WALKER[0], radius=_WALKER[1]))
    for i in range(config.num_cyclists):
        speed = rng.uniform(*CYCLE_SPEED)
        traj = _pick(_lane_candidates(rng, layout, ego_x_mid, t_mid, i, speed), *_RIDER, t, obstacles)
        parts, pedalling = cyclist_parts(rng, speed)
        people.append(_person(f"cyclist_{i}", parts, 1.0 / pedalling.frequency, traj, first_id + len(people),
                              "Bicycle", {"attributes.rider_status": "With Rider"}, rng))
        obstacles.append(_Obstacle(*traj.pose(t), discs=_RIDER[0], radius=_RIDER[1]))
    return people
