"""The lidar ground under a vehicle (instances/ground.py) and the smoother's ground-height factor:
a plane fitted through the road's cells under kerbs, parked cars and walls, on level and sloped
roads, and a far vehicle whose registrations climb kept on the road."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from idsplat_ns.data.geometry import so3_exp
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.ground import GroundConfig, GroundSurface, fit_ground_height
from idsplat_ns.instances.smoothing import SmoothingConfig, smooth_trajectory


def _road_points(rng: np.random.Generator, slope: tuple[float, float] = (0.0, 0.0), height: float = -1.9,
                 extent: float = 30.0, sweeps: int = 4) -> list[np.ndarray]:
    """Lidar points of a planar road (``height`` at the origin, rising ``slope`` per metre in x
    and y, 1 cm noise) with a kerb and pavement (+0.15 m) beyond y = 5, a wall at y = 9, a parked
    car (a 4.5 x 1.8 x 1.5 m block of points on its surface) at x = 3, y = 3.5, and a few returns
    0.4 m below the road (multipath); one array per sweep."""
    out = []
    for _ in range(sweeps):
        xy = rng.uniform(-extent, extent, (6000, 2))
        z = height + xy @ np.asarray(slope) + rng.normal(0.0, 0.01, len(xy))
        z[xy[:, 1] > 5.0] += 0.15
        wall = np.column_stack([rng.uniform(-extent, extent, 800), np.full(800, 9.0), rng.uniform(0, 3, 800)])
        wall[:, 2] += height + wall[:, :2] @ np.asarray(slope) + 0.15
        car = np.column_stack([rng.uniform(0.75, 5.25, 600), rng.uniform(2.6, 4.4, 600), rng.uniform(0.3, 1.5, 600)])
        car[:, 2] += height + car[:, :2] @ np.asarray(slope)
        pts = np.column_stack([xy, z])
        low = pts[rng.choice(len(pts), 20, replace=False)] - [0.0, 0.0, 0.4]
        out.append(np.concatenate([pts, wall, car, low]))
    return out


@pytest.mark.parametrize("slope", [(0.0, 0.0), (0.1, 0.0), (-0.06, 0.03)])
def test_ground_follows_level_and_sloped_roads_beside_objects(slope: tuple[float, float]) -> None:
    """Within 3 cm of the road under queries on the open road, next to the parked car and the
    kerb; the cells of the car, the wall and the multipath returns do not lift or sink it."""
    rng = np.random.default_rng(0)
    ground = GroundSurface.from_point_sets(_road_points(rng, slope))
    queries = np.array([[0.0, 0.0], [-12.0, -6.0], [3.0, 1.5], [3.0, 3.5], [10.0, 4.0], [-20.0, 2.0]])
    truth = -1.9 + queries @ np.asarray(slope)
    np.testing.assert_allclose(ground.heights_at(queries), truth, atol=0.03)


def test_ground_is_unknown_away_from_the_lidar_points() -> None:
    ground = GroundSurface.from_point_sets(_road_points(np.random.default_rng(1)))
    assert np.isnan(ground.heights_at(np.array([[80.0, 0.0]]))).all()
    empty = GroundSurface.from_point_sets([])
    assert np.isnan(empty.heights_at(np.zeros((2, 2)))).all()


def test_cell_heights_are_low_order_statistics_of_all_sweeps() -> None:
    """A cell's height is its ``cell_rank``-th lowest point over all sweeps together, whichever
    sweep the points came from; a cell with fewer points uses its highest."""
    config = GroundConfig(cell_size=1.0, cell_rank=2)
    a = np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 0.2], [2.5, -0.5, 5.0]])
    b = np.array([[0.4, 0.6, 0.1], [0.6, 0.4, 3.0], [0.5, 0.5, 0.6]])
    ground = GroundSurface.from_point_sets([a, b], config)
    cells = {tuple(c): h for c, h in zip(ground.centres, ground.heights)}
    assert cells[(0.5, 0.5)] == pytest.approx(0.6)  # 0.1, 0.2, 0.6, 1.0, 3.0 -> third lowest
    assert cells[(2.5, -0.5)] == pytest.approx(5.0)


def test_plane_fit_drops_cells_above_and_far_below() -> None:
    """A tilted plane of cells, a block of object cells 1 m above and two 2 m below: the height
    under the query is the plane's."""
    g = np.linspace(-3.5, 3.5, 15)
    offsets = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    heights = 0.08 * offsets[:, 0] - 0.05 * offsets[:, 1] + 1.0
    heights[(offsets[:, 0] > 0.5) & (offsets[:, 1] > 0.5)] += 1.0
    heights[:2] -= 2.0
    assert fit_ground_height(offsets, heights, GroundConfig()) == pytest.approx(1.0, abs=1e-6)
    assert np.isnan(fit_ground_height(offsets[:3], heights[:3], GroundConfig()))


def _far_climbing_bus(seed: int, slope: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A vehicle driving straight at 7 m/s for 1.8 s on a road rising ``slope`` per metre along x,
    registered like seed 12's far bus: heights drift 1.2 m upwards across the track (the lidar
    lines sweep over a rear face), plus 3 cm noise. Returns times [T], truth [T, 4, 4], measured."""
    rng = np.random.default_rng(seed)
    times = np.arange(10) * 0.2
    truth = np.tile(np.eye(4), (len(times), 1, 1))
    truth[:, :3, :3] = so3_exp(np.array([0.0, -math.atan(slope), 0.0]))  # pitched up the road
    truth[:, 0, 3] = 60.0 + 7.0 * times
    truth[:, 2, 3] = -0.4 + slope * truth[:, 0, 3]
    meas = truth.copy()
    meas[:, 2, 3] += np.linspace(-0.6, 0.6, len(times))
    meas[:, :3, 3] += rng.normal(0.0, 0.03, (len(times), 3))
    return times, truth, meas


@pytest.mark.parametrize("slope", [0.0, 0.08])
def test_ground_keeps_a_far_vehicle_on_the_road(slope: float) -> None:
    """Registrations that climb 1.2 m: without the ground the smoothed heights follow them (more
    than 0.4 m off at the ends); with the lidar ground they stay within 0.1 m of the road's rise
    (after the constant offset between canonical origin and box, which nothing here measures)."""
    def road(xy: np.ndarray) -> np.ndarray:
        return -1.9 + slope * xy[:, 0]

    for seed in range(3):
        times, truth, meas = _far_climbing_bus(seed, slope)
        valid = np.ones(len(times), bool)
        free = smooth_trajectory(times, meas, valid, SmoothingConfig(ground_height_walk_rate=None))
        kept = smooth_trajectory(times, meas, valid, SmoothingConfig(), ground=road)

        def spread(poses: np.ndarray) -> float:
            dz = poses[:, 2, 3] - truth[:, 2, 3]
            return float(np.max(np.abs(dz - dz.mean())))

        assert spread(free.poses) > 0.4
        assert spread(kept.poses) < 0.1


def test_ground_factor_needs_ground_on_both_steps() -> None:
    """Where the ground is unknown (NaN) the factor is left out: the result is the ground-free
    smoother's there, and nothing fails."""
    times, truth, meas = _far_climbing_bus(0)
    valid = np.ones(len(times), bool)
    unknown = smooth_trajectory(times, meas, valid, ground=lambda xy: np.full(len(xy), np.nan))
    free = smooth_trajectory(times, meas, valid, SmoothingConfig(ground_height_walk_rate=None))
    np.testing.assert_allclose(unknown.poses, free.poses, atol=1e-9)


@pytest.mark.parametrize("field,value", [("cell_size", 0.0), ("search_radius", -1.0), ("min_cells", 2), ("cell_rank", -1)])
def test_ground_settings_are_checked(field: str, value: float) -> None:
    with pytest.raises(IDSplatError, match="smoothing.ground"):
        replace(GroundConfig(), **{field: value})


def test_ground_walk_rate_is_checked() -> None:
    with pytest.raises(IDSplatError, match="ground-height-walk-rate"):
        SmoothingConfig(ground_height_walk_rate=0.0)


def test_ground_query_positions_reach_the_track_ends() -> None:
    """The ground is read on a local straight line through the measurements: exact at a track's
    ends (a running median pulls them a step inwards, which halved the ground's rise there) and
    unmoved by one wrong measurement among five."""
    from idsplat_ns.instances.smoothing.smoother import local_line_positions

    times = np.arange(8) * 0.2
    xy = np.column_stack([60.0 + 7.0 * times, 2.0 - 1.0 * times])
    measured = xy.copy()
    measured[5] += [3.0, -2.0]
    use = np.ones(8, bool)
    use[2] = False
    np.testing.assert_allclose(local_line_positions(times, measured, use), xy, atol=1e-9)
