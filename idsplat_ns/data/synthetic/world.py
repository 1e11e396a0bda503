"""Layout of the synthetic street: road, sidewalks, buildings, poles, trees and vehicles.

Everything is built in a *local* street frame (metres, z up, ground at z = 0): the main road runs
along local +x, the ego drives along it in the right lane, and a side street joins from the left
(+y side). `World.local_to_world` places that frame on Earth (large UTM-like offset and a yaw).

Shapes are analytic parts (`shapes.py`) grouped into objects; an object is static or follows a
trajectory (vehicles: `vehicles.py`; people: `people.py`). Parts of people also move inside their
object (`Part.motion`: limbs, cranks, wheels). Object 0 is the ground plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idsplat_ns.data.synthetic import materials as mat
from idsplat_ns.data.synthetic import traffic
from idsplat_ns.data.synthetic.config import SyntheticConfig
from idsplat_ns.data.synthetic.people_placement import place_people
from idsplat_ns.data.synthetic.shapes import (
    CYLINDER, ELLIPSOID, PLANE, Part, SceneObject, StreetLayout, box_part, yaw_matrix,
)  # fmt: skip
from idsplat_ns.data.synthetic.trajectories import Straight
from idsplat_ns.data.synthetic.vehicles import VEHICLE_SIZES, drawn_vehicles, fixed_vehicles


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
            part = box_part(mat.BUILDING, (x, y_lo, 0.0), (x + width, y_hi, height), np.clip(color, 0, 1), style)
            out.append(SceneObject(f"building_{len(out)}", [part]))
            x += width + (rng.uniform(1.5, 5) if rng.random() < 0.35 else 0.0)
    # Two buildings along the side street, facing it.
    sx, hw = layout.side_street_x, layout.side_street_half_width + 3.0
    for side in (-1, 1):
        y0 = layout.building_line + 18.0 + rng.uniform(0, 4)
        depth = rng.uniform(12, 18)
        x_lo, x_hi = (sx + hw, sx + hw + depth) if side > 0 else (sx - hw - depth, sx - hw)
        color = BUILDING_COLORS[rng.integers(len(BUILDING_COLORS))]
        part = box_part(mat.BUILDING, (x_lo, y0, 0.0), (x_hi, y0 + rng.uniform(15, 25), rng.uniform(8, 20)),
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
            out.append(SceneObject(f"sidewalk_{len(out)}", [box_part(mat.SIDEWALK, lo_k, hi_k, color)]))
    return out


def _street_light(x: float, side: int, y_curb: float) -> SceneObject:
    y = side * (y_curb + 0.5)
    pole_h = 7.0
    parts = [
        Part(CYLINDER, mat.POLE, np.array([x, y, pole_h / 2]), np.array([0.11, 0.11, pole_h / 2]),
             color=np.array([0.42, 0.44, 0.45])),
        box_part(mat.POLE, (x - 0.06, min(y, y - side * 1.8), pole_h - 0.18), (x + 0.06, max(y, y - side * 1.8), pole_h - 0.06),
             (0.42, 0.44, 0.45)),
        box_part(mat.LAMP, (x - 0.22, y - side * 1.8 - 0.3, pole_h - 0.32), (x + 0.22, y - side * 1.8 + 0.3, pole_h - 0.12),
             (0.98, 0.95, 0.82)),
    ]
    return SceneObject("street_light", parts)


SIGN_COLORS = np.array([[0.75, 0.08, 0.07], [0.08, 0.25, 0.65], [0.07, 0.45, 0.2], [0.9, 0.75, 0.1]])


def _sign(x: float, side: int, y_curb: float, color: np.ndarray, style: int) -> SceneObject:
    y = side * (y_curb + 0.35)
    parts = [
        Part(CYLINDER, mat.POLE, np.array([x, y, 1.4]), np.array([0.05, 0.05, 1.4]), color=np.array([0.55, 0.56, 0.58])),
        box_part(mat.SIGN, (x - 0.04, y - 0.4, 2.0), (x + 0.04, y + 0.4, 2.8), color, style),
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


def build_world(config: SyntheticConfig, seed: int) -> World:
    """The street for `config`, varied by `seed` (building sizes and colours, furniture, car colours).

    People are drawn from their own random stream, so the street and its vehicles are the same
    with or without them.
    """
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
        vehicles = fixed_vehicles(rng, layout, config, ego)
    else:
        vehicles = drawn_vehicles(traffic_rng, layout, config, ego)
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
