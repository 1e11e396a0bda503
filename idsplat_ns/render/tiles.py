"""Tile intersection: which Gaussians can touch which tile, sorted by tile then depth.

A Gaussian can only contribute where ``alpha >= 1/255``, i.e. where
``sigma <= log(255 * opacity)``. That set is an ellipse whose axis-aligned bounding box has
half-widths ``sqrt(2 log(255 o) cov_xx)`` and ``sqrt(2 log(255 o) cov_yy)``; it is usually much
smaller than gsplat's 3-sigma square, which keeps the number of (tile, Gaussian) pairs low. The
box is exact (a superset of every pixel the Gaussian can affect), so tiling never changes the
image. Sorting uses integer keys only (PyTorch's radix sort), which is several times faster on CPU
than sorting float depths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

from .reference import ALPHA_MIN


@dataclass
class TileIntersections:
    """(tile, Gaussian) pairs sorted by global tile index, front to back within a tile."""

    gaussian_ids: Tensor  # [I] int64 index into the flattened [C*N] Gaussians
    tile_ids: Tensor  # [I] int64 global tile index: camera * tiles_per_camera + row * tiles_x + col
    tile_offsets: Tensor  # [C * tiles_per_camera + 1] int64 start of each tile's run
    tile_size: int  # tile side in pixels
    tiles_x: int  # tiles per image row
    tiles_y: int  # tiles per image column
    num_cameras: int  # C
    # Irregular sample positions (lidar rays) instead of the B*B pixel centres of each tile:
    slot_x: Optional[Tensor] = None  # [T, S] x of each slot (pixel units), None for cameras
    slot_y: Optional[Tensor] = None  # [T, S] y of each slot
    slot_valid: Optional[Tensor] = None  # [T, S] bool, False for padding slots
    period_x: Optional[float] = None  # x wraps around with this period (lidar azimuth)

    @property
    def slots_per_tile(self) -> int:
        """Samples per tile: B*B pixels, or S ray slots."""
        return self.tile_size**2 if self.slot_x is None else self.slot_x.shape[1]

    @property
    def num_tiles(self) -> int:
        """Tiles over all cameras."""
        return self.num_cameras * self.tiles_x * self.tiles_y


def alpha_extent(
    covars2d: Tensor,  # [G, 3] (xx, xy, yy) blurred 2D covariance
    opacities: Tensor,  # [G]
) -> Tensor:
    """Half-widths [G, 2] (pixels) of the box outside which ``alpha < 1/255``; <0 if nowhere."""
    level = torch.log(opacities.clamp_min(1e-30) / ALPHA_MIN)  # sigma at which alpha = 1/255
    ext = torch.sqrt(2.0 * level.clamp_min(0.0)[:, None] * covars2d[:, [0, 2]].clamp_min(0.0))
    # A tiny margin so that float rounding at the boundary never drops a pixel.
    ext = ext * (1.0 + 1e-4) + 1e-3
    return torch.where(level[:, None] > 0, ext, torch.full_like(ext, -1.0))


@torch.no_grad()
def intersect_tiles(
    means2d: Tensor,  # [C, N, 2]
    covars2d: Tensor,  # [C, N, 3]
    depths: Tensor,  # [C, N]
    radii: Tensor,  # [C, N] int, 0 = culled
    opacities: Tensor,  # [N], or [C, N] one per camera (lidar time bins with their own Gaussians)
    width: int,
    height: int,
    tile_size: int,
    wrap_x: bool = False,
    samples_anywhere: bool = False,
) -> TileIntersections:
    """All (tile, Gaussian) pairs, sorted by tile and front to back inside each tile.

    ``wrap_x``: x is periodic with period ``width`` (a multiple of ``tile_size``), as lidar
    azimuth is; a Gaussian across the seam then touches tiles at both ends.
    ``samples_anywhere``: samples lie anywhere in their cell (lidar rays), not at its centre.
    """
    cams, n = depths.shape
    device = means2d.device
    tiles_x = math.ceil(width / tile_size)
    tiles_y = math.ceil(height / tile_size)
    per_cam = tiles_x * tiles_y

    # Depth order over all cameras at once (camera major): sort float depths once, then use
    # their rank as an integer key together with the camera index.
    flat_depth = depths.reshape(-1).float()
    cam_idx = torch.arange(cams, device=device).repeat_interleave(n)
    ext = alpha_extent(covars2d.reshape(-1, 3), opacities.reshape(-1) if opacities.dim() == 2 else opacities.repeat(cams))
    mx, my = means2d.reshape(-1, 2).unbind(-1)
    # Cells x whose sample (centre x + 0.5, or anywhere in [x, x + 1)) can lie in the box.
    half = 0.0 if samples_anywhere else 0.5
    round_lo = torch.floor if samples_anywhere else torch.ceil
    x_lo = round_lo(mx - ext[:, 0] - half)
    x_hi = torch.floor(mx + ext[:, 0] - half)
    if wrap_x:  # keep the unclamped range (tiles are taken modulo tiles_x below)
        x_lo = torch.where(x_hi - x_lo + 1 >= width, torch.zeros_like(x_lo), x_lo).clamp(-width, 2 * width)
        x_hi = torch.minimum(x_hi, x_lo + width - 1).clamp(-width, 2 * width)
    else:
        x_lo, x_hi = x_lo.clamp(0, width - 1), x_hi.clamp(-1, width - 1)
    y_lo = round_lo(my - ext[:, 1] - half).clamp(0, height - 1)
    y_hi = torch.floor(my + ext[:, 1] - half).clamp(-1, height - 1)
    ok = (
        (radii.reshape(-1) > 0)
        & (ext[:, 0] >= 0)
        & (x_hi >= x_lo)
        & (y_hi >= y_lo)
        & torch.isfinite(mx)
        & torch.isfinite(my)
    )
    gid = torch.nonzero(ok).squeeze(1)
    # index_select throughout: advanced indexing is several times slower on CPU.
    # Front to back: order the surviving Gaussians by depth, sorting integer keys (a radix sort,
    # several times faster than a float sort): float32 bit patterns read as int32 order like the
    # numbers once the bits of negative numbers (other than the sign) are flipped.
    bits = flat_depth.index_select(0, gid).view(torch.int32)
    order = torch.sort(bits ^ ((bits >> 31) & 0x7FFFFFFF), stable=True).indices
    gid = gid.index_select(0, order)
    tx0, tx1, ty0, ty1 = (
        torch.div(v.index_select(0, gid), tile_size, rounding_mode="floor").long()
        for v in (x_lo, x_hi, y_lo, y_hi)
    )
    nx = tx1 - tx0 + 1
    counts = nx * (ty1 - ty0 + 1)
    total = int(counts.sum())
    rep = torch.repeat_interleave(torch.arange(gid.numel(), device=device), counts, output_size=total)
    starts = torch.cumsum(counts, 0) - counts
    local = torch.arange(total, device=device) - starts.index_select(0, rep)
    nx_r = nx.index_select(0, rep)
    row = torch.div(local, nx_r, rounding_mode="floor")
    col = local - row * nx_r
    if wrap_x:
        tile_x = (tx0.index_select(0, rep) + col) % tiles_x
        base = cam_idx.index_select(0, gid) * per_cam + ty0 * tiles_x  # [G']
        tile_ids = base.index_select(0, rep) + row * tiles_x + tile_x
    else:
        base = cam_idx.index_select(0, gid) * per_cam + ty0 * tiles_x + tx0  # first tile of each
        tile_ids = base.index_select(0, rep) + row * tiles_x + col
    key = tile_ids.to(torch.int32) if cams * per_cam < 2**31 else tile_ids
    # Stable integer sort by tile keeps the depth order inside each tile.
    perm = torch.sort(key, stable=True).indices
    tile_ids = tile_ids.index_select(0, perm)
    gaussian_ids = gid.index_select(0, rep.index_select(0, perm))
    counts_per_tile = torch.bincount(tile_ids, minlength=cams * per_cam)
    offsets = torch.zeros(cams * per_cam + 1, dtype=torch.int64, device=device)
    offsets[1:] = torch.cumsum(counts_per_tile, 0)
    return TileIntersections(
        gaussian_ids=gaussian_ids,
        tile_ids=tile_ids,
        tile_offsets=offsets,
        tile_size=tile_size,
        tiles_x=tiles_x,
        tiles_y=tiles_y,
        num_cameras=cams,
    )


def tile_centres(
    tile_ids: Tensor,  # [M] int64 global tile index (camera or time bin major)
    tiles_x: int,
    tiles_y: int,
    tile_size: int,
) -> tuple[Tensor, Tensor]:
    """Centres (x, y) [M] float64, in pixels (or grid cells), of the tiles ``tile_ids``."""
    local = tile_ids % (tiles_x * tiles_y)
    col = (local % tiles_x).double()
    row = torch.div(local, tiles_x, rounding_mode="floor").double()
    return col * tile_size + 0.5 * tile_size, row * tile_size + 0.5 * tile_size


def tiles_to_image(x: Tensor, isects: TileIntersections, width: int, height: int) -> Tensor:
    """[T*B*B, D] tile-pixel rows (tile-major, row-major inside a tile) to [C, H, W, D] images."""
    b = isects.tile_size
    d = x.shape[-1]
    img = x.reshape(isects.num_cameras, isects.tiles_y, isects.tiles_x, b, b, d)
    img = img.permute(0, 1, 3, 2, 4, 5).reshape(
        isects.num_cameras, isects.tiles_y * b, isects.tiles_x * b, d
    )
    return img[:, :height, :width]
