"""Traffic of the built-in street that varies with the seed (data/synthetic/traffic.py): the path
motion against closed forms, the manoeuvres' geometry, clearances against an independent footprint
test, the `fixed` street unchanged, and what the `varied` and `hard` presets hold."""

from __future__ import annotations

import numpy as np
import pytest

from idsplat_ns.data.synthetic import traffic
from idsplat_ns.data.synthetic.cli import config_from_args
from idsplat_ns.data.synthetic.config import config_to_dict, get_preset
from idsplat_ns.data.synthetic.trajectories import Straight
from idsplat_ns.data.synthetic.shapes import StreetLayout
from idsplat_ns.data.synthetic.world import build_world
from idsplat_ns.errors import IDSplatError


def _road(ego_lane: float = -1.75, duration: float = 3.9) -> traffic.Road:
    layout = StreetLayout()
    return traffic.Road(layout.lane_width, layout.road_half_width - layout.parking_width / 2, layout.side_street_x,
                        layout.side_street_half_width, duration, Straight(0.0, ego_lane, 0.0, 8.0))  # fmt: skip


def test_path_motion_on_a_straight_is_constant_velocity():
    path = traffic._Path(2.0, 1.0, 0.3).straight(50.0)
    motion = traffic._constant_speed(path, 7.0, t_ref=1.0, s_ref=10.0, duration=4.0)
    ref = Straight(2.0 + 3.0 * np.cos(0.3), 1.0 + 3.0 * np.sin(0.3), 0.3, 7.0)  # at s = 3 when t = 0
    t = np.array([-1.5, 0.0, 0.7, 3.9, 5.0, 9.0])  # before the knots, between, after the path's end
    xy, heading = motion.pose(t)
    xy_ref, heading_ref = ref.pose(t)
    np.testing.assert_allclose(xy, xy_ref, atol=1e-9)
    np.testing.assert_allclose(heading, heading_ref, atol=1e-9)


def test_arc_and_lane_shift_geometry():
    # A left quarter turn of radius 5 from (0, 0) heading +x ends at (5, 5) heading +y.
    path = traffic._Path(0.0, 0.0, 0.0).arc(5.0, np.pi / 2)
    np.testing.assert_allclose(path.end, [5.0, 5.0], atol=1e-9)
    assert path.heading == pytest.approx(np.pi / 2)
    assert path.length() == pytest.approx(5.0 * np.pi / 2, rel=1e-3)
    # A right U-turn ends 2r to the right, heading back.
    path = traffic._Path(0.0, 0.0, 0.0).arc(3.5, -np.pi)
    np.testing.assert_allclose(path.end, [0.0, -7.0], atol=1e-9)
    # A lane change: 3.5 m to the left over 30 m, no kink at its ends.
    path = traffic._Path(0.0, 0.0, 0.0).straight(10.0).shift(3.5, 30.0).straight(10.0)
    pts = path.points()
    np.testing.assert_allclose(pts[-1], [50.0, 3.5], atol=1e-9)
    heading = np.arctan2(np.diff(pts[:, 1]), np.diff(pts[:, 0]))
    assert np.abs(np.diff(heading)).max() < np.radians(0.5)
    motion = traffic._constant_speed(path, 5.0, 0.0, 0.0, 10.0)
    _, h = motion.pose(np.linspace(0, 10, 400))
    assert np.abs(np.diff(h)).max() < np.radians(0.5) and h.max() > np.radians(8)


def test_stop_and_go_stands_still_then_drives_on():
    path = traffic._Path(0.0, 0.0, 0.0).straight(200.0)
    motion = traffic._stop_and_go(path, 8.0, 20.0, t_brake=0.5, decel=4.0, wait=1.0, accel=4.0, duration=6.0)
    t = np.linspace(-1.0, 6.0, 701)
    s = motion.distance_at(t)
    v = np.gradient(s, t)
    assert np.all(np.diff(s) >= -1e-9) and s[np.argmin(np.abs(t))] == pytest.approx(20.0)
    stopped = (t > 2.6) & (t < 3.4)  # braking ends at 0.5 + 8 / 4 = 2.5 s, driving resumes at 3.5 s (8 m/s at 5.5 s)
    assert np.abs(v[stopped]).max() < 1e-6
    assert v[t < 0.4].min() == pytest.approx(8.0, abs=1e-6) and v[-1] == pytest.approx(8.0, abs=0.05)
    assert s[stopped][0] == pytest.approx(20.0 + 8.0 * 0.5 + 8.0**2 / (2 * 4.0), abs=0.01)  # closed form


@pytest.mark.parametrize("name", sorted(traffic.MANOEUVRES))
def test_each_manoeuvre_happens_inside_the_sequence(name):
    road = _road()
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, road.duration, 80)
    for _ in range(5):
        label, traj = traffic.MANOEUVRES[name](rng, road)
        assert label in traffic.VEHICLE_DIMENSIONS
        xy, heading = traj.pose(t)
        ego = road.ego.pose(t)[0]
        assert np.all(np.isfinite(xy)) and np.linalg.norm(xy - ego, axis=1).min() < 60.0  # within sensor reach
        turned = np.abs(np.unwrap(heading)[-1] - np.unwrap(heading)[0])
        if name.startswith("turn_"):  # the turn is done inside the sequence: about 90 degrees of it
            assert turned > 0.7 * np.pi / 2 - 1e-6 and label not in traffic.LONG_VEHICLES
        elif name == "u_turn":
            assert turned > 0.7 * np.pi - 1e-6
        elif name == "oncoming_long":
            assert label in traffic.LONG_VEHICLES and abs(np.cos(heading[0]) + 1) < 1e-9


def _rectangle(xy, heading, length, width) -> np.ndarray:
    """Densely sampled outline [M, 2] of an oriented rectangle (2 cm apart)."""
    u = np.linspace(-0.5, 0.5, int(length / 0.02) + 1)
    v = np.linspace(-0.5, 0.5, int(width / 0.02) + 1)
    local = np.concatenate([np.c_[u * length, np.full_like(u, w * width)] for w in (-0.5, 0.5)]
                           + [np.c_[np.full_like(v, s * length), v * width] for s in (-0.5, 0.5)])  # fmt: skip
    c, s = np.cos(heading), np.sin(heading)
    return local @ np.array([[c, s], [-s, c]]) + xy


def _rectangle_gap(a, b) -> float:
    """Distance between two rectangles' outlines (0 where they cross): the reference for the discs."""
    pa, pb = _rectangle(*a), _rectangle(*b)
    return float(np.min(np.linalg.norm(pa[:, None] - pb[None], axis=-1)))


@pytest.mark.parametrize("preset, seed", [("hard", 0), ("hard", 5), ("varied", 2)])
def test_vehicles_never_touch_each_other_or_the_ego(preset, seed):
    world = build_world(get_preset(preset), seed)
    t = np.linspace(-0.1, world.config.duration + 0.1, 57)
    boxes = [(world.ego, traffic.EGO_SIZE[0], traffic.EGO_SIZE[1])]
    boxes += [(v.trajectory, v.dimensions[1], v.dimensions[0]) for v in world.vehicles]
    poses = [traj.pose(t) for traj, _, _ in boxes]
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            if i > 0 and not (world.vehicles[i - 1].moving or world.vehicles[j - 1].moving):
                continue  # two parked vehicles: placed apart along the curb
            centre_gap = np.linalg.norm(poses[i][0] - poses[j][0], axis=1)
            near = np.flatnonzero(centre_gap < (boxes[i][1] + boxes[j][1]) / 2 + 1.0)
            for k in near:
                gap = _rectangle_gap((poses[i][0][k], poses[i][1][k], boxes[i][1], boxes[i][2]),
                                     (poses[j][0][k], poses[j][1][k], boxes[j][1], boxes[j][2]))  # fmt: skip
                assert gap > traffic.CLEARANCE - 0.03, (i, j, t[k])  # the discs' gap bounds it (2 cm outline samples)


def test_fixed_traffic_is_the_streets_of_before():
    world = build_world(get_preset("small"), 0)
    movers = [(v.name, v.label) for v in world.vehicles if v.moving]
    assert [n for n, _ in movers] == ["leading_car", "overtaking_car", "oncoming_car", "oncoming_bus", "turning_car"]
    assert world.ego.y0 == pytest.approx(-1.5 * StreetLayout().lane_width)
    assert "traffic" not in config_to_dict(get_preset("small"))  # cached streets keep their generator.json
    assert config_to_dict(get_preset("hard"))["traffic"] == "hard"


def test_hard_street_packs_the_close_cases():
    names, lateral, long_oncoming = [], [], 0
    for seed in range(6):
        world = build_world(get_preset("hard"), seed)
        assert world.ego.y0 == pytest.approx(-0.5 * StreetLayout().lane_width)  # traffic on both sides
        movers = [v for v in world.vehicles if v.moving]
        names += [v.name for v in movers]
        t = np.linspace(0, world.config.duration, 60)
        ego = world.ego.pose(t)[0]
        for v in movers:
            if v.name in ("overtaking", "oncoming", "oncoming_long"):
                xy = v.trajectory.pose(t)[0]
                k = np.argmin(np.abs(xy[:, 0] - ego[:, 0]))  # level with the ego
                if abs(xy[k, 0] - ego[k, 0]) < 2.0:
                    lateral.append(abs(xy[k, 1] - ego[k, 1]))
            long_oncoming += v.name == "oncoming_long" and v.label in traffic.LONG_VEHICLES
    assert set(traffic.HARD) <= set(names)
    assert len(lateral) >= 12 and max(lateral) <= 7.0 + 1e-9 and min(lateral) <= 3.5 + 1e-9  # passes within 2-7 m
    assert long_oncoming >= 5


def test_varied_streets_differ_from_seed_to_seed():
    counts, lanes, kinds = [], set(), set()
    for seed in range(12):
        world = build_world(get_preset("varied"), seed)
        movers = [v for v in world.vehicles if v.moving]
        counts.append(len(movers))
        lanes.add(round(world.ego.y0, 2))
        kinds |= {v.name for v in movers} | {v.label for v in world.vehicles}
    assert len(set(counts)) >= 5 and max(counts) <= traffic.MAX_MOVERS
    assert len(lanes) == 2
    assert len(kinds & set(traffic.MANOEUVRES)) >= 10 and {"Medium-sized Truck", "Semi-truck", "Bus"} & kinds


def test_traffic_option_names_the_street_and_checks_its_value():
    assert config_from_args("bench", None, None, traffic="hard").name == "bench_hard"
    assert config_from_args("hard", None, None, traffic="hard").name == "hard"
    assert config_from_args("small", None, None).traffic == "fixed"
    with pytest.raises(IDSplatError, match="traffic='busy'"):
        get_preset(config_from_args("small", None, None).__class__(traffic="busy"))
