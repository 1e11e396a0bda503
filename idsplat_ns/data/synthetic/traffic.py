"""Traffic of the built-in street that varies with the seed: which vehicles move, how, and where
the ego drives (``SyntheticConfig.traffic``).

* ``fixed``: the five manoeuvres of every seed (``world._vehicles``: leading car, overtaking car,
  oncoming car, oncoming bus, a right turn out of the side street), the ego in the right lane;
  the demo's and the tests' street, unchanged by this module.
* ``varied``: per seed, 0-15 moving vehicles drawn from :data:`MANOEUVRES`, with their classes
  (cars, pickups, medium trucks, buses, semi-trucks) and speeds, 2-7 parked on the right curb and
  1-5 on the left (trucks among them: occluders); the ego in the right or the fast lane.
* ``hard``: the cases where annotation-free tracking is hardest, packed into one street: the ego
  in the fast lane, so that traffic passes within 3.5 m on both sides; an overtaking vehicle from
  behind on the right, two oncoming on the left (one long vehicle seen end-on first), a right turn
  out of the side street and a left turn into it, both completed in view, a cut-in lane change,
  stop-and-go, a U-turn, a leading and a following vehicle.

Every mover is placed by drawing its manoeuvre's free parameters until its footprint keeps
``CLEARANCE`` from the ego, the parked vehicles and the movers placed before it over the whole
sequence (footprints as chains of discs); a manoeuvre that finds no clear draw is left out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from idsplat_ns.data.synthetic.trajectories import PathMotion, Stationary, Straight, Trajectory

VEHICLE_DIMENSIONS = {  # label: (length, width, height), metres
    "Car": (4.5, 1.82, 1.48),
    "Pickup Truck": (5.4, 1.98, 1.85),
    "Medium-sized Truck": (8.0, 2.4, 3.2),
    "Bus": (11.0, 2.5, 3.1),
    "Semi-truck": (16.5, 2.55, 3.9),
}
LONG_VEHICLES = ("Medium-sized Truck", "Bus", "Semi-truck")
"""Classes that only drive straight here (a semi-truck would bend in a turn; it is rigid)."""
MOVER_CLASSES = {"Car": 0.62, "Pickup Truck": 0.16, "Medium-sized Truck": 0.1, "Bus": 0.06, "Semi-truck": 0.06}
"""Class of a straight-driving mover and its probability."""
PARKED_CLASSES = {"Car": 0.8, "Pickup Truck": 0.12, "Medium-sized Truck": 0.08}
"""Class of a parked vehicle and its probability."""
CLEARANCE = 0.5
"""Smallest gap (m) between two footprints (vehicles, the ego) at any time of the sequence."""
EGO_SIZE = (4.7, 1.9)
"""Length and width (m) of the ego's footprint."""
STEP = 0.25
"""Spacing (m) of the points of a path."""


@dataclass(frozen=True)
class Road:
    """What a manoeuvre needs of the street and the ego (local frame, metres, seconds)."""

    lane_width: float
    parking_y: float  # |y| of the parking strips' centre lines
    side_street_x: float
    side_street_half_width: float
    duration: float
    ego: Straight

    @property
    def right(self) -> float:  # y of the ego-direction right lane
        return -1.5 * self.lane_width

    @property
    def fast(self) -> float:  # y of the ego-direction fast lane
        return -0.5 * self.lane_width

    @property
    def oncoming_inner(self) -> float:
        return 0.5 * self.lane_width

    @property
    def oncoming_outer(self) -> float:
        return 1.5 * self.lane_width

    @property
    def other_lane(self) -> float:
        """The ego-direction lane the ego is not in."""
        return self.fast if abs(self.ego.y0 - self.right) < 1e-6 else self.right

    def ego_x(self, t: float) -> float:
        return self.ego.x0 + self.ego.speed * t


@dataclass(frozen=True)
class Mover:
    """A placed moving vehicle."""

    manoeuvre: str
    label: str
    trajectory: Trajectory


class _Path:
    """A path built piece by piece: straights, arcs and smooth lane shifts."""

    def __init__(self, x: float, y: float, heading: float) -> None:
        self.pieces = [np.array([[x, y]], dtype=np.float64)]
        self.heading = heading

    @property
    def end(self) -> np.ndarray:
        return self.pieces[-1][-1]

    def straight(self, length: float) -> _Path:
        u = np.linspace(0.0, length, max(1, int(np.ceil(length / STEP))) + 1)[1:]
        self.pieces.append(self.end + u[:, None] * _unit(self.heading))
        return self

    def arc(self, radius: float, angle: float) -> _Path:
        """A circular arc turning by ``angle`` (radians; positive turns left)."""
        sign = np.sign(angle)
        centre = self.end + sign * radius * _unit(self.heading + np.pi / 2)
        headings = self.heading + np.linspace(0.0, angle, max(2, int(np.ceil(abs(angle) * radius / STEP))) + 1)[1:]
        self.pieces.append(centre - sign * radius * _unit(headings + np.pi / 2))
        self.heading += angle
        return self

    def shift(self, lateral: float, length: float) -> _Path:
        """A lane change: ``lateral`` metres to the left (negative: right) over ``length`` metres,
        the offset a smoothstep of the distance (no kink at either end)."""
        u = np.linspace(0.0, length, max(2, int(np.ceil(length / STEP))) + 1)[1:]
        w = u / length
        offset = lateral * w * w * (3 - 2 * w)
        self.pieces.append(self.end + u[:, None] * _unit(self.heading) + offset[:, None] * _unit(self.heading + np.pi / 2))
        return self

    def points(self) -> np.ndarray:  # [P, 2]
        return np.concatenate(self.pieces)

    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points(), axis=0), axis=1).sum())


def _unit(angle) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def _constant_speed(path: _Path, speed: float, t_ref: float, s_ref: float, duration: float) -> PathMotion:
    """Along ``path`` at ``speed``, at distance ``s_ref`` at time ``t_ref``."""
    times = np.array([-2.0, duration + 2.0])
    return PathMotion(path.points(), times, s_ref + speed * (times - t_ref))


def _stop_and_go(path: _Path, speed: float, s0: float, t_brake: float, decel: float, wait: float, accel: float,
                 duration: float) -> PathMotion:  # fmt: skip
    """Along ``path`` at ``speed`` from distance ``s0`` at t = 0, braking at ``t_brake`` to a stop,
    standing ``wait`` seconds, then back to ``speed``."""
    t = np.arange(-2.0, duration + 2.0 + 1e-9, 0.02)
    t_stop = t_brake + speed / decel
    t_go = t_stop + wait
    v = np.where(t < t_brake, speed, np.where(t < t_stop, speed - decel * (t - t_brake), 0.0))
    v = np.where(t >= t_go, np.minimum(speed, accel * (t - t_go)), v)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    s += s0 - np.interp(0.0, t, s)
    return PathMotion(path.points(), t, s)


def _class(rng: np.random.Generator, table: dict[str, float], turning: bool = False) -> str:
    names = [k for k in table if not (turning and k in LONG_VEHICLES)]
    p = np.array([table[k] for k in names])
    return str(rng.choice(names, p=p / p.sum()))


# -- the manoeuvres: each draws its free parameters and returns (label, trajectory) ------------------

Draw = Callable[[np.random.Generator, Road], tuple[str, Trajectory]]


def leading(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Ahead in a same-direction lane (the ego's more often), a little slower or faster."""
    y = road.ego.y0 if rng.random() < 0.6 else road.other_lane
    return _class(rng, MOVER_CLASSES), Straight(road.ego_x(0) + rng.uniform(12, 35), y, 0.0,
                                                road.ego.speed + rng.uniform(-1.0, 2.0))


def following(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Behind the ego in its lane (the lidar sees it; the cameras face forward)."""
    return _class(rng, MOVER_CLASSES), Straight(road.ego_x(0) - rng.uniform(10, 18), road.ego.y0, 0.0,
                                                road.ego.speed + rng.uniform(-1.0, 0.8))


def overtaking(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """From behind in the other same-direction lane, level with the ego inside the sequence."""
    dv, t_pass = rng.uniform(3.0, 7.0), rng.uniform(0.25, 0.8) * road.duration
    return _class(rng, MOVER_CLASSES), Straight(road.ego_x(0) - dv * t_pass, road.other_lane, 0.0, road.ego.speed + dv)


def passed_by_ego(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Slower, ahead in the other same-direction lane: the ego draws level with it and passes."""
    dv, t_pass = rng.uniform(2.5, 5.0), rng.uniform(0.3, 0.85) * road.duration
    return _class(rng, MOVER_CLASSES), Straight(road.ego_x(0) + dv * t_pass, road.other_lane, 0.0, road.ego.speed - dv)


def oncoming(rng: np.random.Generator, road: Road, long: bool = False) -> tuple[str, Trajectory]:
    """In an opposite lane (the inner one more often), meeting the ego inside the sequence."""
    y = road.oncoming_inner if rng.random() < 0.65 else road.oncoming_outer
    v, t_meet = rng.uniform(6.0, 12.0), rng.uniform(0.15, 0.95) * road.duration
    label = str(rng.choice(LONG_VEHICLES)) if long else _class(rng, MOVER_CLASSES)
    return label, Straight(road.ego_x(t_meet) + v * t_meet, y, np.pi, v)


def oncoming_long(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """A bus or truck oncoming: the lidar sees its front face first, end-on."""
    return oncoming(rng, road, long=True)


def _side_street_in(road: Road, lane_x: float) -> tuple[float, float]:
    return lane_x, 60.0  # far up the side street


def _turn_end(rng: np.random.Generator, road: Road, earliest: float, arc: float, speed: float) -> float:
    """When a turn of ``arc`` metres at ``speed`` ends: drawn in [``earliest`` D, 0.95 D], and late
    enough that at least 70 % of the arc is driven inside the sequence."""
    lo = max(earliest * road.duration, 0.7 * arc / speed)
    return rng.uniform(min(lo, 0.95 * road.duration), 0.95 * road.duration)


def turn_out_right(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Down the side street, right into the outer opposite lane; the turn ends inside the sequence."""
    r, v = rng.uniform(5.0, 7.0), rng.uniform(4.0, 6.0)
    x, y = _side_street_in(road, road.side_street_x - road.side_street_half_width / 2)
    path = _Path(x, y, -np.pi / 2).straight(y - (road.oncoming_outer + r)).arc(r, -np.pi / 2).straight(80.0)
    s_end = (y - road.oncoming_outer - r) + r * np.pi / 2
    return _class(rng, MOVER_CLASSES, turning=True), _constant_speed(
        path, v, _turn_end(rng, road, 0.5, r * np.pi / 2, v), s_end, road.duration)


def turn_out_left(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Down the side street, left across the opposite lanes into a same-direction lane ahead of the ego."""
    r, v = rng.uniform(8.0, 11.0), rng.uniform(4.0, 6.0)
    lane = road.right if rng.random() < 0.5 else road.fast
    x, y = _side_street_in(road, road.side_street_x - road.side_street_half_width / 2)
    path = _Path(x, y, -np.pi / 2).straight(y - (lane + r)).arc(r, np.pi / 2).straight(80.0)
    s_end = (y - lane - r) + r * np.pi / 2
    return _class(rng, MOVER_CLASSES, turning=True), _constant_speed(
        path, v, _turn_end(rng, road, 0.4, r * np.pi / 2, v), s_end, road.duration)


def turn_in_left(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Ahead in a same-direction lane, left into the side street across the opposite lanes."""
    r, v = rng.uniform(7.0, 10.0), rng.uniform(4.0, 6.5)
    lane = road.other_lane if rng.random() < 0.5 else road.ego.y0
    x_arc = road.side_street_x + road.side_street_half_width / 2 - r
    path = _Path(x_arc - 80.0, lane, 0.0).straight(80.0).arc(r, np.pi / 2).straight(60.0)
    s_end = 80.0 + r * np.pi / 2
    return _class(rng, MOVER_CLASSES, turning=True), _constant_speed(
        path, v, _turn_end(rng, road, 0.3, r * np.pi / 2, v), s_end, road.duration)


def turn_in_right(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Oncoming in the outer lane, right into the side street."""
    r, v = rng.uniform(4.0, 6.0), rng.uniform(4.0, 6.0)
    x_arc = road.side_street_x + road.side_street_half_width / 2 + r
    path = _Path(x_arc + 80.0, road.oncoming_outer, np.pi).straight(80.0).arc(r, -np.pi / 2).straight(60.0)
    s_end = 80.0 + r * np.pi / 2
    return _class(rng, MOVER_CLASSES, turning=True), _constant_speed(
        path, v, _turn_end(rng, road, 0.3, r * np.pi / 2, v), s_end, road.duration)


def lane_change(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Ahead in one same-direction lane, changing into the other (a cut-in when it is the ego's)."""
    into_ego = rng.random() < 0.6
    y0 = road.other_lane if into_ego else road.ego.y0
    lateral = (road.ego.y0 if into_ego else road.other_lane) - y0
    v = road.ego.speed + rng.uniform(0.0, 2.5)
    x0 = road.ego_x(0) + rng.uniform(6.0, 22.0)
    lead = v * rng.uniform(0.1, 0.5) * road.duration  # the change starts inside the sequence
    path = _Path(x0 - 60.0, y0, 0.0).straight(60.0 + lead).shift(lateral, rng.uniform(20.0, 35.0)).straight(80.0)
    return _class(rng, MOVER_CLASSES), _constant_speed(path, v, 0.0, 60.0, road.duration)


def stop_and_go(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Ahead, braking to a stop, standing, driving on (the other same-direction lane or an opposite one)."""
    v = rng.uniform(6.0, 9.0)
    if rng.random() < 0.5:
        path, x0 = _Path(road.ego_x(0) - 60.0, road.other_lane, 0.0).straight(200.0), 60.0 + rng.uniform(10.0, 30.0)
    else:
        start = road.ego_x(0) + 140.0
        path, x0 = _Path(start, road.oncoming_inner, np.pi).straight(200.0), rng.uniform(60.0, 110.0)
    return _class(rng, MOVER_CLASSES), _stop_and_go(
        path, v, x0, rng.uniform(0.05, 0.35) * road.duration, rng.uniform(3.0, 4.5), rng.uniform(0.3, 1.2),
        rng.uniform(1.5, 2.5), road.duration)  # fmt: skip


def u_turn(rng: np.random.Generator, road: Road) -> tuple[str, Trajectory]:
    """Ahead in the fast lane, turning back into the outer opposite lane; the turn ends inside the sequence."""
    r = (road.oncoming_outer - road.fast) / 2
    v = rng.uniform(3.0, 4.5)
    x_arc = road.ego_x(0) + rng.uniform(25.0, 45.0)
    path = _Path(x_arc - 60.0, road.fast, 0.0).straight(60.0).arc(r, np.pi).straight(80.0)
    s_end = 60.0 + r * np.pi
    return _class(rng, MOVER_CLASSES, turning=True), _constant_speed(
        path, v, _turn_end(rng, road, 0.5, r * np.pi, v), s_end, road.duration)


MANOEUVRES: dict[str, Draw] = {
    "leading": leading,
    "following": following,
    "overtaking": overtaking,
    "passed_by_ego": passed_by_ego,
    "oncoming": oncoming,
    "oncoming_long": oncoming_long,
    "turn_out_right": turn_out_right,
    "turn_out_left": turn_out_left,
    "turn_in_left": turn_in_left,
    "turn_in_right": turn_in_right,
    "lane_change": lane_change,
    "stop_and_go": stop_and_go,
    "u_turn": u_turn,
}
"""Every manoeuvre by name (the name goes to ``idsplat_extras/instances.json``)."""

HARD = ("overtaking", "oncoming", "oncoming_long", "turn_out_right", "turn_in_left", "lane_change", "stop_and_go",
        "u_turn", "leading", "following")  # fmt: skip
"""The ``hard`` street's movers, placed in this order (the closest passes first). Not ``passed_by_ego``:
with the ego in the fast lane it shares the right lane with the overtaking vehicle, which always
catches it up inside the sequence."""

MAX_MOVERS = 15
"""Most moving vehicles of a ``varied`` street."""


# -- placement ---------------------------------------------------------------------------------------


def footprint_discs(length: float, width: float) -> tuple[np.ndarray, float]:
    """Offsets [K] along the length and the radius of discs that cover a ``length`` x ``width``
    footprint: each circumscribes one of K equal slices no longer than half the width, so a gap
    between discs is a lower bound of the gap between the rectangles (at most ~0.06 width less)."""
    k = max(1, int(np.ceil(length / (0.5 * width))))
    slice_len = length / k
    return -length / 2 + (np.arange(k) + 0.5) * slice_len, float(np.hypot(slice_len / 2, width / 2))


def footprint_centres(traj: Trajectory, length: float, width: float, t: np.ndarray) -> np.ndarray:
    """Disc centres [T, K, 2] of a footprint of ``length`` x ``width`` over times ``t`` [T]
    (radius: :func:`footprint_discs`)."""
    xy, heading = traj.pose(t)
    return xy[:, None, :] + footprint_discs(length, width)[0][None, :, None] * _unit(heading)[:, None, :]


def footprint_gap(a: np.ndarray, ra: float, b: np.ndarray, rb: float) -> float:
    """Smallest gap (m) between two footprints' discs [T, K, 2] and [T, M, 2] over the times."""
    d = np.linalg.norm(a[:, :, None, :] - b[:, None, :, :], axis=-1)
    return float(d.min() - ra - rb)


def parked_vehicles(rng: np.random.Generator, road: Road) -> list[tuple[str, Stationary]]:
    """2-7 vehicles on the right curb and 1-5 on the left (the side street's mouth kept clear), bumper
    gaps of 1-3 m at least; trucks among them hide what is behind."""
    out = []
    for side, count in ((-1, rng.integers(2, 8)), (1, rng.integers(1, 6))):
        placed: list[tuple[float, float]] = []  # (x, length)
        for _ in range(int(count)):
            label = _class(rng, PARKED_CLASSES)
            length = VEHICLE_DIMENSIONS[label][0]
            for _try in range(20):
                x = rng.uniform(-25.0, 110.0)
                if side > 0 and abs(x - road.side_street_x) < road.side_street_half_width + 4.0 + length / 2:
                    continue
                if all(abs(x - px) >= (length + pl) / 2 + rng.uniform(1.0, 3.0) for px, pl in placed):
                    placed.append((x, length))
                    heading = (0.0 if side < 0 else np.pi) + rng.uniform(-0.03, 0.03)
                    out.append((label, Stationary(x, side * road.parking_y + rng.uniform(-0.15, 0.1), heading)))
                    break
    return out


def place_movers(rng: np.random.Generator, road: Road, names: list[str], obstacles: list[tuple[Trajectory, str]],
                 num_frames: int, tries: int = 40) -> list[Mover]:  # fmt: skip
    """Movers for the manoeuvres ``names`` in order, each kept ``CLEARANCE`` from the ego, the
    ``obstacles`` (trajectory, label) and the movers before it; a manoeuvre with no clear draw in
    ``tries`` is left out."""
    t = np.linspace(-0.1, road.duration + 0.1, max(24, 4 * num_frames))
    placed = [(footprint_centres(road.ego, *EGO_SIZE, t), footprint_discs(*EGO_SIZE)[1])]
    for traj, label in obstacles:
        length, width, _ = VEHICLE_DIMENSIONS[label]
        placed.append((footprint_centres(traj, length, width, t), footprint_discs(length, width)[1]))
    movers = []
    for name in names:
        for _ in range(tries):
            label, traj = MANOEUVRES[name](rng, road)
            length, width, _ = VEHICLE_DIMENSIONS[label]
            mine, radius = footprint_centres(traj, length, width, t), footprint_discs(length, width)[1]
            if all(footprint_gap(mine, radius, other, r) >= CLEARANCE for other, r in placed):
                placed.append((mine, radius))
                movers.append(Mover(name, label, traj))
                break
    return movers


def draw_manoeuvres(rng: np.random.Generator, kind: str) -> list[str]:
    """The manoeuvres of a ``varied`` (0-15, drawn with repetition) or ``hard`` street."""
    if kind == "hard":
        return list(HARD)
    count = int(rng.integers(0, MAX_MOVERS + 1))
    names = sorted(MANOEUVRES)
    return [str(n) for n in rng.choice(names, size=count, replace=True)]


def ego_lane(rng: np.random.Generator, kind: str, road_right: float, road_fast: float) -> float:
    """The ego's lane: the right one for ``fixed``, the fast one for ``hard`` (traffic on both
    sides), either for ``varied``."""
    if kind == "fixed":
        return road_right
    if kind == "hard":
        return road_fast
    return road_right if rng.random() < 0.5 else road_fast
