"""Vehicles of the synthetic street: their parts (cars, pickups, buses, box trucks, tractors with
trailers) and the two kinds of traffic: the five fixed manoeuvres of every seed, and traffic drawn
per seed (:mod:`idsplat_ns.data.synthetic.traffic`)."""

from __future__ import annotations

import uuid

import numpy as np

from idsplat_ns.data.synthetic import materials as mat
from idsplat_ns.data.synthetic import traffic
from idsplat_ns.data.synthetic.config import SyntheticConfig
from idsplat_ns.data.synthetic.shapes import CYLINDER, Part, SceneObject, StreetLayout, box_part
from idsplat_ns.data.synthetic.traffic import VEHICLE_DIMENSIONS
from idsplat_ns.data.synthetic.trajectories import Stationary, Straight, StraightArcStraight, Trajectory

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
        box_part(mat.CAR_BODY, (hl - cab, -hw, 0.45), (hl, hw, 1.5), color, style),
        box_part(mat.CAR_CABIN, (hl - cab, -0.95 * hw, 1.5), (hl - 0.1, 0.95 * hw, cab_height), color, style),
        box_part(mat.BUS_BODY, (-hl, -hw, 1.0), (hl - cab - 0.2, hw, height), (0.82, 0.82, 0.8), style),
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
        parts.append(box_part(mat.BUS_BODY, (-hl, -hw, 0.3), (hl, hw, height), color, style))
    else:
        belt = 0.95 if label == "Car" else 1.1  # top of the lower body
        parts.append(box_part(mat.CAR_BODY, (-hl, -hw, 0.26), (hl, hw, belt), color, style))
        if label == "Car":
            cab_lo, cab_hi = -0.32 * length, 0.2 * length
        else:  # pickup: short cab at the front, open bed behind
            cab_lo, cab_hi = -0.08 * length, 0.24 * length
        parts.append(box_part(mat.CAR_CABIN, (cab_lo, -0.92 * hw, belt), (cab_hi, 0.92 * hw, height), color, style))
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


def fixed_vehicles(rng: np.random.Generator, layout: StreetLayout, config: SyntheticConfig, ego: Straight) -> list[SceneObject]:
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
    return _vehicle_objects(rng, specs, colors)


def _vehicle_objects(rng: np.random.Generator, specs: list[tuple[str, str, Trajectory, bool]],
                     colors: np.ndarray) -> list[SceneObject]:  # fmt: skip
    """Scene objects of (name, label, trajectory, moving) specs, instance IDs 1, 2, ... in order,
    painted in ``colors`` in turn (buses orange)."""
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


def drawn_vehicles(rng: np.random.Generator, layout: StreetLayout, config: SyntheticConfig, ego: Straight) -> list[SceneObject]:
    """Parked and moving vehicles of a ``varied`` or ``hard`` street (:mod:`traffic`)."""
    road = traffic.Road(layout.lane_width, layout.road_half_width - layout.parking_width / 2, layout.side_street_x,
                        layout.side_street_half_width, config.duration, ego)  # fmt: skip
    parked = traffic.parked_vehicles(rng, road)
    movers = traffic.place_movers(rng, road, traffic.draw_manoeuvres(rng, config.traffic),
                                  [(traj, label) for label, traj in parked], config.num_frames)  # fmt: skip
    specs = [("parked_truck" if label in traffic.LONG_VEHICLES else "parked_car", label, traj, False)
             for label, traj in parked]  # fmt: skip
    specs += [(m.manoeuvre, m.label, m.trajectory, True) for m in movers]
    return _vehicle_objects(rng, specs, CAR_COLORS[rng.permutation(len(CAR_COLORS))])
