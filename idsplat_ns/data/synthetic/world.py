"""Layout of the synthetic street: road, sidewalks, buildings, poles, trees and vehicles.

Everything is built in a *local* street frame (metres, z up, ground at z = 0): the main road runs
along local +x, the ego drives along it in the right lane, and a side street joins from the left
(+y side). `World.local_to_world` places that frame on Earth (large UTM-like offset and a yaw).

Shapes are analytic parts (boxes, vertical-axis cylinders, ellipsoids) grouped into objects; an
object is static or follows a trajectory (vehicles, people). Parts of people also move inside their
object (`Part.motion`: limbs, cranks, wheels; see `people.py`). Object 0 is the ground plane.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from idsplat_ns.data.synthetic import materials as mat
from idsplat_ns.data.synthetic.config import SyntheticConfig
from idsplat_ns.data.synthetic import traffic
from idsplat_ns.data.synthetic.traffic import VEHICLE_DIMENSIONS
from idsplat_ns.data.synthetic.trajectories import (
    Stationary,
    Straight,
    StraightArcStraight,
    Trajectory,
)

PLANE, BOX, CYLINDER, ELLIPSOID = 0, 1, 2, 3
"""Part kinds. Cylinders have their axis along the part's z; ellipsoids are axis aligned."""


class PartMotion(Protocol):
    """Pose of a part in its object's frame over time (a swinging limb, a turning crank)."""

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre [N, 3] and object-from-part rotation [N, 3, 3] at times `t` [N]."""
        ...


@dataclass
class Part:
    """One analytic shape, placed in its object's frame."""

    kind: int
    """PLANE, BOX, CYLINDER or ELLIPSOID."""
    material: int
    """Material id (see `materials`)."""
    center: np.ndarray  # [3]
    """Centre in the object frame."""
    size: np.ndarray  # [3]
    """Box: half extents; cylinder: (radius, radius, half height); ellipsoid: radii."""
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # [3, 3]
    """Object-from-part rotation (columns are the part axes in the object frame)."""
    color: np.ndarray = field(default_factory=lambda: np.full(3, 0.5))  # [3]
    """Base colour, linear-ish RGB in [0, 1]."""
    style: int = 0
    """Texture variant (facade style, hash seed of a window pattern, ...)."""
    motion: PartMotion | None = None
    """Pose in the object frame over time; None for parts fixed in their object (`center`, `rotation`)."""


@dataclass
class SceneObject:
    """A group of parts; vehicles and people are instances with cuboid ground truth."""

    name: str
    """Readable name (`building_3`, `parked_car_0`, `turning_car`)."""
    parts: list[Part]
    """The shapes, in the object frame (x forward, y left, z up for vehicles)."""
    trajectory: Trajectory | None = None
    """Pose over time in the local frame; None for the static street."""
    instance_id: int = 0
    """0 for background, k >= 1 for vehicles and people (the value in the instance masks)."""
    label: str = ""
    """PandaSet cuboid label ("Car", "Pickup Truck", "Bus", "Pedestrian", "Bicycle")."""
    moving: bool = False
    """True for road users that move during the sequence."""
    dimensions: tuple[float, float, float] | None = None
    """(width, length, height) of the cuboid; it stands on the ground, centred on the object origin in
    x and y, and holds every part at every time (moving limbs included)."""
    uuid: str = ""
    """Track id in the cuboid annotations."""
    attributes: dict[str, str] = field(default_factory=dict)
    """Extra cuboid columns (`attributes.pedestrian_behavior`, `attributes.rider_status`, ...)."""

    @property
    def articulated(self) -> bool:
        """Whether some part moves inside the object (then it is not a rigid body)."""
        return any(part.motion is not None for part in self.parts)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre [3] (object frame) and radius of a sphere that holds every part (at every time)."""
        if self.articulated:  # moving parts: the cuboid holds them at every time
            width, length, height = self.dimensions
            return np.array([0.0, 0.0, height / 2]), float(np.linalg.norm([length / 2, width / 2, height / 2]))
        corners = []
        for part in self.parts:
            signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
            corners.append(part.center + (signs * part.size) @ part.rotation.T)
        pts = np.concatenate(corners)
        centre = 0.5 * (pts.min(0) + pts.max(0))
        return centre, float(np.linalg.norm(pts - centre, axis=1).max())


@dataclass(frozen=True)
class StreetLayout:
    """Fixed dimensions of the street (local frame)."""

    lane_width: float = 3.5
    """Width of each of the four driving lanes (two per direction)."""
    parking_width: float = 2.0
    """Parking strip between the outer lane and the curb, both sides."""
    sidewalk_width: float = 4.0
    """Sidewalk from the curb to the building line."""
    curb_height: float = 0.15
    """Height of the sidewalks above the road."""
    side_street_x: float = 45.0
    """Local x of the side street's centre line (it joins from the left, +y)."""
    side_street_half_width: float = 4.0
    """Half width of the side street's road."""
    x_min: float = -50.0
    """Start of the built-up street."""
    x_max: float = 200.0
    """End of the built-up street."""

    @property
    def road_half_width(self) -> float:
        """Curb position |y|."""
        return 2 * self.lane_width + self.parking_width

    @property
    def building_line(self) -> float:
        """|y| of the sidewalk's outer edge, where facades start."""
        return self.road_half_width + self.sidewalk_width


@dataclass
class World:
    """The whole synthetic scene: static street, vehicles, ego motion, light and placement."""

    config: SyntheticConfig
    """The configuration it was built from."""
    seed: int
    """The seed it was built from."""
    layout: StreetLayout
    """Street dimensions."""
    objects: list[SceneObject]
    """Object 0 is the ground plane; vehicles carry instance ids."""
    ego: Straight
    """Ego trajectory (its footprint centre) in the local frame."""
    sun_direction: np.ndarray  # [3]
    """Unit vector towards the sun, local frame."""
    local_to_world_rotation: np.ndarray  # [3, 3]
    """Rotation of the local street frame into the world frame."""
    local_to_world_offset: np.ndarray  # [3]
    """World position of the local origin (float64)."""

    @property
    def road_users(self) -> list[SceneObject]:
        """Objects with an instance id (vehicles, pedestrians, cyclists), in instance-id order."""
        return sorted((o for o in self.objects if o.instance_id > 0), key=lambda o: o.instance_id)

    @property
    def vehicles(self) -> list[SceneObject]:
        """The vehicles among the road users, in instance-id order."""
        return [o for o in self.road_users if o.label in VEHICLE_SIZES]

    def points_to_world(self, points: np.ndarray) -> np.ndarray:
        """Local points [N, 3] to world points [N, 3] (float64)."""
        return points @ self.local_to_world_rotation.T + self.local_to_world_offset

    def directions_to_world(self, directions: np.ndarray) -> np.ndarray:
        """Local directions [N, 3] to world directions [N, 3]."""
        return directions @ self.local_to_world_rotation.T

    def ego_pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local ego-to-street rotation [N, 3, 3] and position [N, 3] (footprint centre) at `t` [N]."""
        xy, heading = self.ego.pose(t)
        return yaw_matrix(heading), np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], -1)


def yaw_matrix(yaw: np.ndarray) -> np.ndarray:
    """Rotations [N, 3, 3] about z by `yaw` [N] radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros(np.shape(yaw) + (3, 3))
    out[..., 0, 0], out[..., 0, 1] = c, -s
    out[..., 1, 0], out[..., 1, 1] = s, c
    out[..., 2, 2] = 1.0
    return out


def _box(material: int, lo, hi, color=(0.5, 0.5, 0.5), style: int = 0) -> Part:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return Part(BOX, material, 0.5 * (lo + hi), 0.5 * (hi - lo), color=np.asarray(color, float), style=style)


# Wheel cylinders have their axis along the vehicle's y: part z -> object -y.
_WHEEL_ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

CAR_COLORS = np.array(
    [
        [0.86, 0.86, 0.88],  # white
        [0.58, 0.60, 0.63],  # silver
        [0.07, 0.07, 0.08],  # black
        [0.09, 0.17, 0.42],  # dark blue
        [0.62, 0.07, 0.06],  # red
        [0.33, 0.34, 0.36],  # grey
        [0.11, 0.30, 0.17],  # dark green
        [0.72, 0.63, 0.49],  # beige
        [0.42, 0.60, 0.76],  # light blue
        [0.88, 0.68, 0.08],  # yellow
        [0.45, 0.18, 0.10],  # brown
    ]
)

VEHICLE_SIZES = VEHICLE_DIMENSIONS
"""label: (length, width, height) of every vehicle class the street has."""


def _wheel(x: float, y: float, r: float) -> Part:
    return Part(CYLINDER, mat.WHEEL, np.array([x, y, r]), np.array([r, r, 0.12]), rotation=_WHEEL_ROTATION,
                color=np.array([0.05, 0.05, 0.05]))


def _truck_parts(label: str, color: np.ndarray, style: int) -> list[Part]:
    """A box truck or a tractor with its trailer (one rigid object): a cab at the front, a cargo box
    behind it, wheels on their axles."""
    length, width, height = VEHICLE_SIZES[label]
    hl, hw = length / 2, width / 2
    cab = 2.0 if label == "Medium-sized Truck" else 3.0
    cab_height = 2.6 if label == "Medium-sized Truck" else 3.2
    parts = [
        _box(mat.CAR_BODY, (hl - cab, -hw, 0.45), (hl, hw, 1.5), color, style),
        _box(mat.CAR_CABIN, (hl - cab, -0.95 * hw, 1.5), (hl - 0.1, 0.95 * hw, cab_height), color, style),
        _box(mat.BUS_BODY, (-hl, -hw, 1.0), (hl - cab - 0.2, hw, height), (0.82, 0.82, 0.8), style),
    ]
    axles = [hl - 1.2, -hl + 1.6] if label == "Medium-sized Truck" else [hl - 1.2, hl - 4.2, -hl + 1.4, -hl + 2.7]
    for x in axles:
        for sy in (-1, 1):
            parts.append(_wheel(x, sy * (hw - 0.14), 0.5))
    return parts


def vehicle_parts(label: str, color: np.ndarray, style: int) -> list[Part]:
    """Parts of a vehicle in its frame (x forward, y left, z up, origin = footprint centre)."""
    if label in ("Medium-sized Truck", "Semi-truck"):
        return _truck_parts(label, color, style)
    length, width, height = VEHICLE_SIZES[label]
    hl, hw = length / 2, width / 2
    wheel_r = 0.5 if label == "Bus" else 0.34
    parts: list[Part] = []
    if label == "Bus":
        parts.append(_box(mat.BUS_BODY, (-hl, -hw, 0.3), (hl, hw, height), color, style))
    else:
        belt = 0.95 if label == "Car" else 1.1  # top of the lower body
        parts.append(_box(mat.CAR_BODY, (-hl, -hw, 0.26), (hl, hw, belt), color, style))
        if label == "Car":
            cab_lo, cab_hi = -0.32 * length, 0.2 * length
        else:  # pickup: short cab at the front, open bed behind
            cab_lo, cab_hi = -0.08 * length, 0.24 * length
        parts.append(_box(mat.CAR_CABIN, (cab_lo, -0.92 * hw, belt), (cab_hi, 0.92 * hw, height), color, style))
    wheel_x = 0.36 * length if label == "Bus" else 0.31 * length
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(
                Part(
                    CYLINDER,
                    mat.WHEEL,
                    np.array([sx * wheel_x, sy * (hw - 0.11), wheel_r]),
                    np.array([wheel_r, wheel_r, 0.12]),
                    rotation=_WHEEL_ROTATION,
                    color=np.array([0.05, 0.05, 0.05]),
                )
            )
    return parts


BUILDING_COLORS = np.array(
    [
        [0.62, 0.30, 0.22],  # brick red
        [0.80, 0.74, 0.62],  # sand
        [0.70, 0.70, 0.68],  # light grey
        [0.45, 0.47, 0.50],  # concrete
        [0.78, 0.62, 0.45],  # ochre
        [0.55, 0.62, 0.66],  # blue grey
        [0.86, 0.84, 0.78],  # off white
        [0.50, 0.36, 0.28],  # dark brick
        [0.66, 0.74, 0.62],  # pale green
    ]
)


def _buildings(rng: np.random.Generator, layout: StreetLayout) -> list[SceneObject]:
    """Rows of buildings on both sides, with a gap for the side street on the left."""
    out: list[SceneObject] = []
    gap_lo = layout.side_street_x - layout.side_street_half_width - 3.5
    gap_hi = layout.side_street_x + layout.side_street_half_width + 3.5
    for side in (-1, 1):
        x = layout.x_min + rng.uniform(0, 5)
        while x < layout.x_max:
            width = rng.uniform(9, 22)
            if side > 0 and x < gap_hi and x + width > gap_lo:  # leave the side street open
                if x < gap_lo - 4:
                    width = gap_lo - x
                else:
                    x = gap_hi
                    continue
            height = rng.uniform(7, 24)
            depth = rng.uniform(10, 16)
            front = layout.building_line + rng.uniform(0, 1.2)
            y_lo, y_hi = (front, front + depth) if side > 0 else (-front - depth, -front)
            color = BUILDING_COLORS[rng.integers(len(BUILDING_COLORS))] * rng.uniform(0.9, 1.08)
            style = int(rng.integers(0, 1 << 20))
            part = _box(mat.BUILDING, (x, y_lo, 0.0), (x + width, y_hi, height), np.clip(color, 0, 1), style)
            out.append(SceneObject(f"building_{len(out)}", [part]))
            x += width + (rng.uniform(1.5, 5) if rng.random() < 0.35 else 0.0)
    # Two buildings along the side street, facing it.
    sx, hw = layout.side_street_x, layout.side_street_half_width + 3.0
    for side in (-1, 1):
        y0 = layout.building_line + 18.0 + rng.uniform(0, 4)
        depth = rng.uniform(12, 18)
        x_lo, x_hi = (sx + hw, sx + hw + depth) if side > 0 else (sx - hw - depth, sx - hw)
        color = BUILDING_COLORS[rng.integers(len(BUILDING_COLORS))]
        part = _box(mat.BUILDING, (x_lo, y0, 0.0), (x_hi, y0 + rng.uniform(15, 25), rng.uniform(8, 20)),
                    color, int(rng.integers(0, 1 << 20)))
        out.append(SceneObject(f"building_{len(out)}", [part]))
    return out


def _sidewalks(layout: StreetLayout) -> list[SceneObject]:
    """Raised sidewalks (boxes whose road-facing side is the curb)."""
    h, r, b = layout.curb_height, layout.road_half_width, layout.building_line + 1.5
    sx, sw = layout.side_street_x, layout.side_street_half_width
    x0, x1 = layout.x_min - 20, layout.x_max + 20
    color = (0.62, 0.61, 0.58)
    boxes = [
        ((x0, -b, 0), (x1, -r, h)),  # right side
        ((x0, r, 0), (sx - sw, b, h)),  # left side, before the side street
        ((sx + sw, r, 0), (x1, b, h)),  # left side, after the side street
        ((sx - sw - 3.0, r, 0), (sx - sw, 90.0, h)),  # side street, both sides
        ((sx + sw, r, 0), (sx + sw + 3.0, 90.0, h)),
    ]
    # Cut into ~16 m pieces: tight bounding spheres make ray culling effective (seams are invisible).
    out = []
    for lo, hi in boxes:
        axis = 0 if hi[0] - lo[0] > hi[1] - lo[1] else 1
        n = max(1, int(np.ceil((hi[axis] - lo[axis]) / 16.0)))
        cuts = np.linspace(lo[axis], hi[axis], n + 1)
        for a, b in zip(cuts[:-1], cuts[1:]):
            lo_k, hi_k = list(lo), list(hi)
            lo_k[axis], hi_k[axis] = a, b
            out.append(SceneObject(f"sidewalk_{len(out)}", [_box(mat.SIDEWALK, lo_k, hi_k, color)]))
    return out


def _street_light(x: float, side: int, y_curb: float) -> SceneObject:
    y = side * (y_curb + 0.5)
    pole_h = 7.0
    parts = [
        Part(CYLINDER, mat.POLE, np.array([x, y, pole_h / 2]), np.array([0.11, 0.11, pole_h / 2]),
             color=np.array([0.42, 0.44, 0.45])),
        _box(mat.POLE, (x - 0.06, min(y, y - side * 1.8), pole_h - 0.18), (x + 0.06, max(y, y - side * 1.8), pole_h - 0.06),
             (0.42, 0.44, 0.45)),
        _box(mat.LAMP, (x - 0.22, y - side * 1.8 - 0.3, pole_h - 0.32), (x + 0.22, y - side * 1.8 + 0.3, pole_h - 0.12),
             (0.98, 0.95, 0.82)),
    ]
    return SceneObject("street_light", parts)


SIGN_COLORS = np.array([[0.75, 0.08, 0.07], [0.08, 0.25, 0.65], [0.07, 0.45, 0.2], [0.9, 0.75, 0.1]])


def _sign(x: float, side: int, y_curb: float, color: np.ndarray, style: int) -> SceneObject:
    y = side * (y_curb + 0.35)
    parts = [
        Part(CYLINDER, mat.POLE, np.array([x, y, 1.4]), np.array([0.05, 0.05, 1.4]), color=np.array([0.55, 0.56, 0.58])),
        _box(mat.SIGN, (x - 0.04, y - 0.4, 2.0), (x + 0.04, y + 0.4, 2.8), color, style),
    ]
    return SceneObject("sign", parts)


def _tree(x: float, y: float, rng: np.random.Generator) -> SceneObject:
    trunk_h = rng.uniform(2.2, 3.0)
    crown = np.array([rng.uniform(1.3, 1.9), rng.uniform(1.3, 1.9), rng.uniform(1.6, 2.3)])
    green = np.array([0.18, 0.36, 0.12]) * rng.uniform(0.8, 1.2)
    parts = [
        Part(CYLINDER, mat.TRUNK, np.array([x, y, trunk_h / 2 + 0.5]), np.array([0.16, 0.16, trunk_h / 2 + 0.5]),
             color=np.array([0.30, 0.22, 0.15])),
        Part(ELLIPSOID, mat.FOLIAGE, np.array([x, y, trunk_h + crown[2] * 0.8]), crown, color=np.clip(green, 0, 1),
             style=int(rng.integers(0, 1 << 20))),
    ]
    return SceneObject("tree", parts)


def _street_furniture(rng: np.random.Generator, layout: StreetLayout) -> list[SceneObject]:
    """Street lights every ~25 m, trees in between, a few signs; the side-street mouth kept clear."""
    out: list[SceneObject] = []
    sx, clear = layout.side_street_x, layout.side_street_half_width + 3.5
    r = layout.road_half_width
    for side in (-1, 1):
        for x in np.arange(layout.x_min, layout.x_max, 25.0) + rng.uniform(0, 8):
            if not (side > 0 and abs(x - sx) < clear):
                out.append(_street_light(float(x), side, r))
        for x in np.arange(layout.x_min + 12, layout.x_max, 16.0):
            x = float(x + rng.uniform(-3, 3))
            if not (side > 0 and abs(x - sx) < clear + 1.0):
                out.append(_tree(x, side * (r + 1.4), rng))
    out.append(_sign(sx - layout.side_street_half_width - 1.0, 1, r, SIGN_COLORS[0], 0))  # stop sign at the corner
    for i, x in enumerate(rng.uniform(5, 80, size=3)):
        side = -1 if i % 2 == 0 else 1
        if side > 0 and abs(x - sx) < clear + 1.0:
            x += 2 * clear
        out.append(_sign(float(x), side, r, SIGN_COLORS[1 + i % 3], i + 1))
    return out


def _vehicles(rng: np.random.Generator, layout: StreetLayout, config: SyntheticConfig, ego: Straight) -> list[SceneObject]:
    """Parked cars along both curbs and five moving vehicles with distinct manoeuvres."""
    duration, v_ego = config.duration, config.ego_speed
    lane = layout.lane_width
    right_lane, fast_lane = -1.5 * lane, -0.5 * lane  # same direction as the ego
    oncoming_inner, oncoming_outer = 0.5 * lane, 1.5 * lane
    park_y = layout.road_half_width - layout.parking_width / 2
    colors = CAR_COLORS[rng.permutation(len(CAR_COLORS))]
    specs: list[tuple[str, str, Trajectory, bool]] = []
    # Parked: four on the right (passed closely by the ego), two on the left.
    for x in (9.0, 17.0, 31.0, 60.0):
        specs.append(("parked_car", "Car", Stationary(x + rng.uniform(-1.5, 1.5), -park_y + rng.uniform(-0.15, 0.1),
                                                      rng.uniform(-0.03, 0.03)), False))
    for x in (20.0, 72.0):
        specs.append(("parked_car", "Car", Stationary(x + rng.uniform(-1.5, 1.5), park_y, np.pi + rng.uniform(-0.03, 0.03)), False))
    specs[2] = ("parked_pickup", "Pickup Truck", specs[2][2], False)
    t_mid = duration / 2
    # Leading car in the ego lane, slightly faster than the ego.
    specs.append(("leading_car", "Car", Straight(ego.x0 + 17.0, right_lane, 0.0, v_ego + 0.4), True))
    # Overtaking car in the adjacent lane: level with the ego's front at mid-sequence.
    dv = 4.5
    specs.append(("overtaking_car", "Car", Straight(ego.x0 + 5.0 - dv * t_mid, fast_lane, 0.0, v_ego + dv), True))
    # Oncoming car in the inner opposite lane: meets the ego at 3/4 of the sequence.
    t_meet, v_on = 0.75 * duration, 9.0
    specs.append(("oncoming_car", "Car", Straight(ego.x0 + v_ego * t_meet + v_on * t_meet, oncoming_inner, np.pi, v_on), True))
    # Bus far ahead in the outer opposite lane.
    specs.append(("oncoming_bus", "Bus", Straight(ego.x0 + 105.0, oncoming_outer, np.pi, 7.0), True))
    # Turning car: down the side street, right turn into the outer opposite lane; mid-turn at mid-sequence.
    radius, v_turn = 6.0, 5.0
    lead_in = 20.0
    turn = StraightArcStraight(
        start_x=layout.side_street_x - layout.side_street_half_width / 2,
        start_y=oncoming_outer + radius + lead_in,
        start_heading=-np.pi / 2,
        lead_in=lead_in,
        radius=radius,
        turn_angle=-np.pi / 2,
        s0=lead_in + radius * np.pi / 4 - v_turn * t_mid,
        speed=v_turn,
    )
    specs.append(("turning_car", "Pickup Truck" if rng.random() < 0.3 else "Car", turn, True))

    out = []
    for k, (name, label, traj, moving) in enumerate(specs):
        length, width, height = VEHICLE_SIZES[label]
        color = colors[k % len(colors)] if label != "Bus" else np.array([0.85, 0.55, 0.1])
        out.append(
            SceneObject(
                name=name,
                parts=vehicle_parts(label, color, int(rng.integers(0, 1 << 20))),
                trajectory=traj,
                instance_id=k + 1,
                label=label,
                moving=moving,
                dimensions=(width, length, height),
                uuid=str(uuid.UUID(bytes=rng.bytes(16), version=4)),
            )
        )
    return out


def _vehicle_objects(rng: np.random.Generator, specs: list[tuple[str, str, Trajectory, bool]]) -> list[SceneObject]:
    """Scene objects of (name, label, trajectory, moving) specs, instance IDs 1, 2, ... in order."""
    colors = CAR_COLORS[rng.permutation(len(CAR_COLORS))]
    out = []
    for k, (name, label, traj, moving) in enumerate(specs):
        length, width, height = VEHICLE_SIZES[label]
        color = colors[k % len(colors)] if label != "Bus" else np.array([0.85, 0.55, 0.1])
        out.append(
            SceneObject(
                name=name,
                parts=vehicle_parts(label, color, int(rng.integers(0, 1 << 20))),
                trajectory=traj,
                instance_id=k + 1,
                label=label,
                moving=moving,
                dimensions=(width, length, height),
                uuid=str(uuid.UUID(bytes=rng.bytes(16), version=4)),
            )
        )
    return out


def _drawn_traffic(rng: np.random.Generator, layout: StreetLayout, config: SyntheticConfig, ego: Straight) -> list[SceneObject]:
    """Parked and moving vehicles of a ``varied`` or ``hard`` street (:mod:`traffic`)."""
    road = traffic.Road(layout.lane_width, layout.road_half_width - layout.parking_width / 2, layout.side_street_x,
                        layout.side_street_half_width, config.duration, ego)  # fmt: skip
    parked = traffic.parked_vehicles(rng, road)
    movers = traffic.place_movers(rng, road, traffic.draw_manoeuvres(rng, config.traffic),
                                  [(traj, label) for label, traj in parked], config.num_frames)  # fmt: skip
    specs = [("parked_truck" if label in traffic.LONG_VEHICLES else "parked_car", label, traj, False)
             for label, traj in parked]  # fmt: skip
    specs += [(m.manoeuvre, m.label, m.trajectory, True) for m in movers]
    return _vehicle_objects(rng, specs)


def build_world(config: SyntheticConfig, seed: int) -> World:
    """The street for `config`, varied by `seed` (building sizes and colours, furniture, car colours).

    People are drawn from their own random stream, so the street and its vehicles are the same
    with or without them.
    """
    from idsplat_ns.data.synthetic.people_placement import place_people  # builds on this module

    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5717]))
    # Drawn traffic has a stream of its own: the street around it is the fixed street's.
    traffic_rng = np.random.default_rng(np.random.SeedSequence([seed, 0x7AFF1C]))
    layout = StreetLayout()
    lane_y = traffic.ego_lane(traffic_rng, config.traffic, -1.5 * layout.lane_width, -0.5 * layout.lane_width)
    ego = Straight(0.0, lane_y, 0.0, config.ego_speed)
    ground = SceneObject("ground", [Part(PLANE, mat.GROUND, np.zeros(3), np.zeros(3))])
    objects = [ground]
    objects += _sidewalks(layout)
    objects += _buildings(rng, layout)
    objects += _street_furniture(rng, layout)
    if config.traffic == "fixed":
        vehicles = _vehicles(rng, layout, config, ego)
    else:
        vehicles = _drawn_traffic(traffic_rng, layout, config, ego)
    objects += vehicles
    people_rng = np.random.default_rng(np.random.SeedSequence([seed, 0x9E0F1E]))
    objects += place_people(people_rng, layout, config, ego, vehicles, first_id=len(vehicles) + 1)
    sun_el, sun_az = np.radians(38.0), np.radians(115.0 + rng.uniform(-20, 20))
    sun = np.array([np.cos(sun_el) * np.cos(sun_az), np.cos(sun_el) * np.sin(sun_az), np.sin(sun_el)])
    return World(
        config=config,
        seed=seed,
        layout=layout,
        objects=objects,
        ego=ego,
        sun_direction=sun,
        local_to_world_rotation=yaw_matrix(np.radians(config.world_yaw_deg)),
        local_to_world_offset=np.asarray(config.world_offset, dtype=np.float64),
    )
