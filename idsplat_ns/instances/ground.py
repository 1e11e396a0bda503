"""Height of the road under a vehicle, from the lidar.

A vehicle rides on the road: its height above the ground changes by no more than its suspension
lets it. Registrations of far vehicles do not say that: a bus's rear face seen by three or four
lidar lines at 50-70 m registers up to 1.2 m higher at the end of its track than at the start, as
the lines sweep over different parts of it (synthetic street, seed 12). The smoother ties each
step's height change to the change of the ground under it (``smoothing.factors.ground_height_factor``);
this module measures that ground.

Method: every returned lidar point of the sequence (world frame) falls in a square cell; a cell's
height is a low order statistic of its points (the lowest few are discarded as noise). Under a
query position, a plane is fitted to the cells within ``search_radius``, iteratively keeping
the cells close to it and dropping those above it (cars, kerbs, walls), so that slopes are
followed and objects ignored. Moving vehicles do not hide the road: other sweeps see it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np
from scipy.ndimage import minimum_filter
from scipy.spatial import cKDTree

from idsplat_ns.errors import IDSplatError
from idsplat_ns.ranges import POSITIVE, bounded


@dataclass(frozen=True)
class GroundConfig:
    """Settings of the lidar ground surface (:class:`GroundSurface`)."""

    cell_size: float = bounded(0.5, POSITIVE)
    """Metres: side of the square cells the lidar points are binned in."""
    cell_rank: int = 2
    """A cell's height is its ``cell_rank``-th lowest point (0-based): the lowest few are
    discarded as noise (multipath returns below the road). A cell with fewer points uses its
    highest."""
    search_radius: float = bounded(4.0, POSITIVE)
    """Metres around a query position whose cells the ground plane is fitted to (a car's
    footprint and a margin where the lidar sees the road beside it)."""
    min_cells: int = 6
    """Fewer ground cells than this within ``search_radius``: the ground there is unknown (NaN)."""
    above_band: float = 0.05
    """Metres: cells more than this above the fitted plane are objects and leave the fit (a kerb
    stands 0.1-0.15 m; a wider band let a fit through road and pavement settle halfway)."""
    below_band: float = 0.5
    """Metres: cells more than this below the fitted plane are outliers and leave the fit."""
    max_slope: float = 0.3
    """Largest road gradient (rise over run) the fitted plane may have; steeper fits (a wall's
    foot beside a ramp) fall back to a level plane through the kept cells."""
    iterations: int = 6
    """Plane fits per query, each keeping the cells within the bands of the previous one."""

    def __post_init__(self) -> None:
        for name in ("cell_size", "search_radius", "above_band", "below_band"):
            if not getattr(self, name) > 0.0:
                raise IDSplatError(f"smoothing.ground.{name.replace('_', '-')} must be > 0 metres, got {getattr(self, name)}")
        if self.cell_rank < 0 or self.min_cells < 3 or self.iterations < 1 or not self.max_slope >= 0.0:
            raise IDSplatError("smoothing.ground: cell-rank must be >= 0, min-cells >= 3, iterations >= 1 and "
                               f"max-slope >= 0; got {self.cell_rank}, {self.min_cells}, {self.iterations}, {self.max_slope}")


def cell_keys(xy: np.ndarray, cell: float) -> np.ndarray:  # xy: [N, 2] -> [N] int64
    """One sortable integer per ``cell``-metre ground cell of each point."""
    ij = np.floor(xy / cell).astype(np.int64)
    return (ij[:, 0] << 32) + (ij[:, 1] & 0xFFFFFFFF)  # two's complement in the low word


def _key_cells(keys: np.ndarray) -> np.ndarray:  # keys: [C] -> [C, 2] int64 cell indices
    i = keys >> 32
    j = (keys & 0xFFFFFFFF).astype(np.int64)
    return np.stack([i, np.where(j >= 2**31, j - 2**32, j)], axis=1)


def _key_centres(keys: np.ndarray, cell: float) -> np.ndarray:  # keys: [C] -> [C, 2]
    return (_key_cells(keys).astype(np.float64) + 0.5) * cell


def _run_bounds(sorted_keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # [M] -> starts [C], ends [C]
    """Start and end (exclusive) index of each run of equal keys in a sorted array."""
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    return starts, np.r_[starts[1:], len(sorted_keys)]


def _lowest_per_cell(keys: np.ndarray, z: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``count`` lowest heights of each cell: (keys [M], heights [M]), sorted by key then height."""
    order = np.lexsort((z, keys))
    keys, z = keys[order], z[order]
    starts, ends = _run_bounds(keys)
    rank = np.arange(len(keys)) - np.repeat(starts, ends - starts)
    keep = rank < count
    return keys[keep], z[keep]


def cell_heights(point_sets: Iterable[np.ndarray], cell: float, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """Sorted keys [C] (:func:`cell_keys`) of the cells that points of ``point_sets`` (chunks of
    world points [N_i, 3], one per sweep) fall in, and each cell's ``rank``-th lowest height [C]
    (the highest there is in a cell with fewer points). Each chunk is reduced to its ``rank`` + 1
    lowest points per cell first, so time and memory follow the cells, not the points."""
    keys, heights = [], []
    for points in point_sets:
        points = np.asarray(points, np.float64)
        if len(points) == 0:
            continue
        k, z = _lowest_per_cell(cell_keys(points[:, :2], cell), points[:, 2], rank + 1)
        keys.append(k)
        heights.append(z)
    if not keys:
        return np.zeros(0, np.int64), np.zeros(0)
    k, z = _lowest_per_cell(np.concatenate(keys), np.concatenate(heights), rank + 1)
    starts, ends = _run_bounds(k)
    return k[starts], z[np.minimum(starts + rank, ends - 1)]


def capped_by_neighbours(keys: np.ndarray, heights: np.ndarray, cell: float, radius: float,
                         slack: float) -> np.ndarray:  # keys, heights: [C] -> [C]
    """Cell heights no higher than the lowest cell within ``radius`` metres plus ``slack``.

    Where the lidar never saw the road in a cell (far away, where the lines thin out, or under
    the vehicles that drive over it) the cell's lowest points are an object's, and its height is
    the object's body: the object's lower points then read as ground. A nearby cell that did see
    the road gives its height. ``radius`` 0: unchanged."""
    if radius <= 0 or len(keys) == 0:
        return heights
    ij = _key_cells(keys)
    ij -= ij.min(0)
    grid = np.full(tuple(ij.max(0) + 1), np.inf)
    grid[ij[:, 0], ij[:, 1]] = heights
    r = int(np.ceil(radius / cell))
    di, dj = np.mgrid[-r : r + 1, -r : r + 1]
    lowest = minimum_filter(grid, footprint=(di * di + dj * dj) * cell * cell <= radius * radius, mode="constant",
                            cval=np.inf)
    return np.minimum(heights, lowest[ij[:, 0], ij[:, 1]] + slack)


class GroundSurface:
    """Cell heights of the lidar points, queried as a locally fitted ground plane."""

    def __init__(self, centres: np.ndarray, heights: np.ndarray, config: GroundConfig) -> None:  # centres: [C, 2], heights: [C]
        self.centres = np.asarray(centres, np.float64)
        self.heights = np.asarray(heights, np.float64)
        self.config = config
        self._tree = cKDTree(self.centres) if len(self.centres) else None

    @classmethod
    def from_point_sets(cls, point_sets: Iterable[np.ndarray], config: GroundConfig | None = None) -> GroundSurface:
        """From world points given in chunks (one per sweep: [N_i, 3]); each chunk is reduced to
        its lowest points per cell first, so memory follows the cells, not the points."""
        config = config or GroundConfig()
        keys, heights = cell_heights(point_sets, config.cell_size, config.cell_rank)
        return cls(_key_centres(keys, config.cell_size), heights, config)

    @classmethod
    def from_sweeps(cls, sweeps: Iterable, config: GroundConfig | None = None) -> GroundSurface:
        """From lidar sweeps (``data.lidar.LidarSweep``): their returned points."""
        return cls.from_point_sets((sweep.points for sweep in sweeps), config)

    def heights_at(self, xy: np.ndarray) -> np.ndarray:  # xy: [M, 2] world -> [M] (NaN: unknown)
        """Height of the ground at each query position, NaN where too few cells are near."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        out = np.full(len(xy), np.nan)
        if self._tree is None:
            return out
        for m, neighbours in enumerate(self._tree.query_ball_point(xy, self.config.search_radius)):
            if len(neighbours) >= self.config.min_cells:
                out[m] = fit_ground_height(self.centres[neighbours] - xy[m], self.heights[neighbours], self.config)
        return out


def fit_ground_height(offsets: np.ndarray, heights: np.ndarray, config: GroundConfig) -> float:  # offsets: [K, 2], heights: [K]
    """Height at offset (0, 0) of the ground plane through cells at ``offsets`` (metres from the
    query) with ``heights``: a level start at their 20% quantile, then plane fits that keep the
    cells within (-below_band, +above_band) of the previous plane. NaN when fewer than
    ``config.min_cells`` cells stay."""
    A = np.column_stack([np.ones(len(offsets)), offsets])
    # A level start at a low quantile keeps the road's lower cells; any subset of a planar road
    # fits the road's plane exactly, whose band then takes in the rest of the road (upslope
    # too) but not a kerb or a car standing above it.
    coef = np.array([float(np.quantile(heights, 0.2)), 0.0, 0.0])
    for iteration in range(config.iterations):
        residual = heights - A @ coef
        keep = (residual <= config.above_band) & (residual >= -config.below_band)
        if keep.sum() < config.min_cells:
            return float("nan")
        new, *_ = np.linalg.lstsq(A[keep], heights[keep], rcond=None)
        if np.hypot(new[1], new[2]) > config.max_slope:
            new = np.array([float(np.median(heights[keep])), 0.0, 0.0])
        converged = np.allclose(new, coef, atol=1e-4)
        coef = new
        if converged:
            break
    return float(coef[0])
