"""Fused tile compositing with a hand-written backward, in blocks of depth ranks.

Each (tile, Gaussian) intersection carries the six coefficients of its exponent as a quadratic
polynomial of the sample offset ``(ex, ey)`` from the tile centre:

``-log(alpha_unclamped) = k0 + k1 ex + k2 ey + k3 ex^2 + k4 ex ey + k5 ey^2``

(:func:`quadratic_coefficients`; ``k0`` includes ``-log(opacity)``). The exponent of every
(intersection, sample) pair is then one matrix product ``coeffs @ basis`` with the fixed
``[6, S]`` monomial basis of the tile's samples, and the gradient of the coefficients is the
product back, ``-(p @ basis^T)``. The coefficients are built with ordinary autograd ops on
``[I, 6]`` tensors (1/S of the work), so only the per-sample loop is hand-written here.

Tiles are processed together in blocks of depth ranks: block k holds rows ``[start, start + L)``
of every tile that still has rows there, padded to ``L`` (a sentinel row with zero alpha), so a
block is a dense ``[tiles, L, S]`` batch: transmittance is a plain ``cumsum`` of ``log(1 - alpha)``
along L (float32; each block starts from the carried log-transmittance), features are summed by a
batched matrix product. A tile whose samples have all reached ``T <= 1e-4`` (gsplat's early
stop) leaves the loop, so the Gaussians behind saturated tiles are never evaluated. ``L`` adapts
so that a block holds about ``block_elems`` values (temporaries stay in cache, memory is bounded).

Backward, for weights ``w_k = alpha_k T_k`` along one sample's list with upstream ``g_k``:
``dL/dalpha_k = g_k T_k - S_k / (1 - alpha_k)`` with ``S_k = sum_{m > k} g_m w_m``, computed block by
block from the back with the suffix sum carried per sample. Rules: :mod:`idsplat_ns.render.reference`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

from .reference import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN

_LOG_T_MIN = math.log(TRANSMITTANCE_MIN)
_LOG_HALF = math.log(0.5)
_T_CLAMP = -math.log(ALPHA_MAX)  # exponent at which alpha reaches the 0.999 clamp
_T_SKIP = -math.log(ALPHA_MIN)  # exponent beyond which alpha < 1/255 is skipped
_ALPHA_CLAMPED = ALPHA_MAX * (1.0 - 1e-6)  # alpha at or above it was clamped (below any rounding of 0.999)
_DROPPED_T = 1e-6  # between the T of dropped rows (< 1e-9) and of live ones (> 1e-4)
_SENTINEL_EXPONENT = 1e30  # padding rows: alpha = 0
_MIN_BLOCK_ROWS = 32  # rows per block at least, so per-tile work (D values per sample) stays small
DEFAULT_BLOCK_ELEMS = 1 << 18  # (row, sample) values per block: 1 MiB float32 per temporary
DEFAULT_CHUNK_ELEMS = DEFAULT_BLOCK_ELEMS  # former name, kept for callers


def monomial_basis(ex: Tensor, ey: Tensor) -> Tensor:
    """``[..., 6, S]`` rows (1, ex, ey, ex^2, ex ey, ey^2) of sample offsets ``ex, ey`` [..., S]."""
    return torch.stack([torch.ones_like(ex), ex, ey, ex * ex, ex * ey, ey * ey], dim=-2)


def pixel_basis(tile_size: int, device, dtype) -> Tensor:
    """Basis [6, B*B] of the pixel centres of a tile (row-major), relative to the tile centre."""
    j = torch.arange(tile_size * tile_size, device=device)
    half = 0.5 * tile_size
    ex = (j % tile_size).to(dtype) + 0.5 - half
    ey = torch.div(j, tile_size, rounding_mode="floor").to(dtype) + 0.5 - half
    return monomial_basis(ex, ey)


def quadratic_coefficients(
    dxc: Tensor,  # [I] mean minus tile centre, x
    dyc: Tensor,  # [I] mean minus tile centre, y
    conics: Tensor,  # [I, 3] (a, b, c)
    opacities: Tensor,  # [I]
) -> Tensor:
    """Coefficients [I, 6] of ``sigma - log(opacity)`` in the sample offset (see module doc).

    ``sigma = 0.5 a dx^2 + b dx dy + 0.5 c dy^2`` with ``dx = dxc - ex``, ``dy = dyc - ey``.
    Differentiable (plain autograd ops). Computed in float64: the polynomial's terms cancel
    near the Gaussian's centre (``k0 ~ a dxc^2`` against ``k1 ex``), which float32 cannot afford.
    """
    f64 = torch.float64
    dxc, dyc, conics, opacities = dxc.to(f64), dyc.to(f64), conics.to(f64), opacities.to(f64)
    a, b, c = conics.unbind(-1)
    log_o = torch.log(opacities.clamp_min(1e-30))
    adx = a * dxc
    cdy = c * dyc
    k0 = 0.5 * (adx * dxc + cdy * dyc) + b * dxc * dyc - log_o
    return torch.stack([k0, -(adx + b * dyc), -(cdy + b * dxc), 0.5 * a, b, 0.5 * c], dim=-1)


@dataclass
class CompositePlan:
    """What :class:`TileComposite` needs besides the differentiable inputs."""

    tile_offsets: Tensor  # [T + 1] int64 start of each tile's depth-sorted run of intersections
    gaussian_ids: Tensor  # [I] int64 row of ``feats`` for each intersection
    basis: Tensor  # [6, S] shared by all tiles, or [T, 6, S] per tile (irregular samples), float64
    slot_valid: Optional[Tensor] = None  # [T, S] float 1/0, 0 for padding samples (lidar)
    block_elems: int = DEFAULT_BLOCK_ELEMS  # target (row, sample) values per block

    @property
    def num_tiles(self) -> int:
        return self.tile_offsets.numel() - 1

    @property
    def slots(self) -> int:
        return self.basis.shape[-1]


@dataclass
class _Block:
    tiles: Tensor  # [Ta] tile indices
    rows: Tensor  # [Ta, L] intersection rows (I = sentinel)
    feats: Tensor  # [Ta, L, D] feature rows of the intersections (gathered once, reused backward)
    alpha: Tensor  # [Ta, L, S]
    trans: Tensor  # [Ta, L, S] transmittance before the row (0 once dropped)


def _below(value: float, dtype: torch.dtype) -> float:
    """The largest number of ``dtype`` below ``value``: ``x > _below(v)`` is ``x >= v`` there."""
    v = torch.tensor(value, dtype=dtype)
    return torch.nextafter(v, torch.tensor(-math.inf, dtype=dtype)).item()


def _exponents(coeffs: Tensor, basis: Tensor, tiles: Tensor) -> Tensor:  # coeffs: [Ta, L, 6]
    if basis.dim() == 2:
        ta, lb, _ = coeffs.shape
        return (coeffs.reshape(-1, 6) @ basis).reshape(ta, lb, basis.shape[1])
    return torch.bmm(coeffs, basis[tiles])


class TileComposite(torch.autograd.Function):
    """Composite all tiles; returns (sample sums [T*S, D], crossing counts [T, S]).

    Inputs: ``coeffs`` [I, 6] (from :func:`quadratic_coefficients`, in the plan's intersection
    order), ``feats`` [G, D] (indexed by ``plan.gaussian_ids``) and the :class:`CompositePlan`.
    ``crossing`` counts, per sample, the rows after which ``T > 0.5`` still holds (the index of
    the median Gaussian in the tile's run when it is smaller than the run length).
    """

    @staticmethod
    def forward(ctx, coeffs, feats, plan: CompositePlan):
        device, dtype = feats.device, feats.dtype
        n_tiles, slots, n_isect, d = plan.num_tiles, plan.slots, coeffs.shape[0], feats.shape[1]
        out = torch.zeros(n_tiles, slots, d, device=device, dtype=dtype)
        crossing = torch.zeros(n_tiles, slots, device=device, dtype=torch.int64)
        blocks = []
        # The coefficients come in float64 (their sum cancels); the exponents are fine in the
        # working precision once the coefficients are exact.
        sentinel = torch.zeros(1, 6, device=device, dtype=dtype)
        sentinel[0, 0] = _SENTINEL_EXPONENT
        coeffs_ext = torch.cat([coeffs.detach().to(dtype), sentinel])
        basis = plan.basis.to(dtype)
        gid_ext = torch.cat([plan.gaussian_ids, plan.gaussian_ids.new_zeros(1)])
        offsets = plan.tile_offsets
        counts = offsets[1:] - offsets[:-1]
        tiles = torch.nonzero(counts > 0).squeeze(1)
        carry = torch.zeros(tiles.numel(), slots, device=device, dtype=dtype)  # log T so far
        # Skipped samples and dropped rows become exact zeros by a threshold pass *after* exp:
        # exp of -inf or of underflowing arguments takes a slow path (3-7x) on CPU, so the
        # arguments are kept finite and well above the underflow range.
        keep_alpha_above = _below(ALPHA_MIN, dtype)  # alpha >= 1/255 kept
        ranks = torch.arange(max(1, int(counts.max())) if n_tiles else 1, device=device)
        start = 0
        while tiles.numel() > 0:
            ta = tiles.numel()
            left = counts[tiles] - start
            lb = min(max(_MIN_BLOCK_ROWS, plan.block_elems // (ta * slots)), int(left.max()))
            rows = offsets[tiles][:, None] + start + ranks[None, :lb]
            rows = torch.where(ranks[None, :lb] < left[:, None], rows, n_isect)
            rows_flat = rows.reshape(-1)
            t = _exponents(coeffs_ext.index_select(0, rows_flat).view(ta, lb, 6), basis, tiles)
            t.neg_().clamp_(-_T_SKIP - 1.0, -_T_CLAMP)  # log alpha, [Ta, L, S]
            # threshold (not masked_fill with a bool mask): several times faster on CPU.
            alpha = torch.nn.functional.threshold_(t.exp_(), keep_alpha_above, 0.0)
            if plan.slot_valid is not None:
                alpha.mul_(plan.slot_valid[tiles][:, None, :])
            log_t = torch.log1p(alpha.neg())
            first = log_t[:, 0, :].clone()
            log_t[:, 0, :] += carry
            incl = torch.cumsum(log_t, 1)  # log T after each row
            log_t[:, 0, :] = first
            crossing.index_add_(0, tiles, (incl > _LOG_HALF).sum(1))
            carry = incl[:, -1, :].clone()
            # Dropped rows (log T after them <= log 1e-4) get log T = -30 + 6.9 at most before
            # the row, so T < 1e-9 there, while live rows have T > 1e-4: the threshold after
            # exp zeroes exactly the dropped rows.
            torch.nn.functional.threshold_(incl, _LOG_T_MIN, -30.0)
            trans = torch.nn.functional.threshold_(incl.sub_(log_t).exp_(), _DROPPED_T, 0.0)
            w = alpha * trans
            f_rows = feats.index_select(0, gid_ext.index_select(0, rows_flat)).view(ta, lb, d)
            out.index_add_(0, tiles, torch.bmm(w.transpose(1, 2), f_rows))
            blocks.append(_Block(tiles=tiles, rows=rows, feats=f_rows, alpha=alpha, trans=trans))
            start += lb
            live = carry > _LOG_T_MIN
            if plan.slot_valid is not None:
                live &= plan.slot_valid[tiles] > 0
            keep = (left > lb) & live.any(1)
            tiles, carry = tiles[keep], carry[keep]
        ctx.plan, ctx.blocks, ctx.n_isect = plan, blocks, n_isect
        ctx.save_for_backward(feats)
        ctx.mark_non_differentiable(crossing)
        return out.reshape(n_tiles * slots, d), crossing

    @staticmethod
    def backward(ctx, grad_out, _grad_crossing):
        (feats,) = ctx.saved_tensors
        plan: CompositePlan = ctx.plan
        n_isect, slots, d = ctx.n_isect, plan.slots, feats.shape[1]
        device, dtype = feats.device, feats.dtype
        g_pix_all = grad_out.reshape(plan.num_tiles, slots, d)
        g_coeffs = torch.zeros(n_isect + 1, 6, device=device, dtype=plan.basis.dtype)
        g_feats = torch.zeros_like(feats)
        gid_ext = torch.cat([plan.gaussian_ids, plan.gaussian_ids.new_zeros(1)])
        clamp_above = -_ALPHA_CLAMPED
        suffix = torch.zeros(plan.num_tiles, slots, device=device, dtype=torch.float64)  # sum g w behind
        for blk in reversed(ctx.blocks):
            tiles, rows, alpha, trans = blk.tiles, blk.rows, blk.alpha, blk.trans
            lb = rows.shape[1]
            g_pix = g_pix_all.index_select(0, tiles)  # [Ta, S, D]
            grad_w = torch.bmm(blk.feats, g_pix.transpose(1, 2))  # [Ta, L, S]
            w = alpha * trans
            if ctx.needs_input_grad[1]:
                gid = gid_ext.index_select(0, rows.reshape(-1))
                g_feats.index_add_(0, gid, torch.bmm(w, g_pix).reshape(-1, d))
            gw = w.mul_(grad_w)
            # S_k = sum_{m > k} g_m w_m: inside the block summed from the back (float32, no
            # cancellation against the block total), plus the float64 sum of the blocks behind.
            rev_incl = torch.cumsum(torch.flip(gw, [1]), 1)  # [j]: sum over rows >= L-1-j
            carried = suffix.index_select(0, tiles)
            suffix[tiles] = carried + rev_incl[:, -1, :].double()
            behind = torch.empty_like(gw)
            behind[:, lb - 1, :] = 0.0
            behind[:, : lb - 1, :] = torch.flip(rev_incl[:, : lb - 1, :], [1])
            behind.add_(carried.to(dtype)[:, None, :])
            behind = behind.div_(torch.rsub(alpha, 1.0))
            # -alpha where alpha is below the clamp, else 0 (clamped alpha: no gradient).
            neg_alpha = torch.nn.functional.threshold_(alpha.neg(), clamp_above, 0.0)
            # p = -(dL/dalpha * alpha), written into a buffer of the basis dtype (float64): its
            # moments must be summed in float64, the chain back to means and conics cancels like
            # the forward (float32 moments fail the dense-reference gradient test).
            basis = plan.basis
            p = torch.empty(alpha.shape, device=device, dtype=basis.dtype)
            torch.mul(grad_w.mul_(trans).sub_(behind), neg_alpha, out=p)
            if basis.dim() == 2:
                r = p.view(-1, slots) @ basis.t()
            else:
                r = torch.bmm(p, basis.index_select(0, tiles).transpose(1, 2)).reshape(-1, 6)
            g_coeffs.index_copy_(0, rows.reshape(-1), r)  # each real row once; sentinel dropped
        return g_coeffs[:n_isect], g_feats, None
