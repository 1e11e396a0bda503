"""Fused tile compositing with a hand-written backward, in cache-sized chunks of tiles.

Intersections (tile, Gaussian), sorted by tile and depth, are expanded to the ``B*B`` pixels of
their tile: a ``[rows, B*B]`` block per chunk in which each tile's run of rows is one
depth-ordered list per pixel column. Transmittance is a segmented cumulative sum of
``log(1 - alpha)`` down the rows, in float64 (so that subtracting a segment's start loses nothing).
Weights are summed into pixels by a sparse CSR product (pixel rows, Gaussian columns) that MKL
runs directly on the features, so no ``[I, D]`` gather is needed in the forward pass.

Work is done one chunk of whole tiles at a time (about ``chunk_elems`` alpha values), so every
temporary stays in the CPU cache and memory is bounded: only alpha and transmittance per
(intersection, pixel) are kept for the backward pass. Rules: :mod:`idsplat_ns.render.reference`.

Backward, for weights ``w_k = alpha_k T_k`` along one pixel's list with upstream ``g_k``:
``dL/dalpha_k = g_k T_k - S_k / (1 - alpha_k)`` with ``S_k = sum_{m > k} g_m w_m`` (a reverse
segmented sum), then the chain rule through ``alpha = o exp(-sigma)`` and the conic form.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import List, Tuple

import torch
from torch import Tensor

from .reference import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN
from .tiles import TileIntersections

_LOG_T_MIN = math.log(TRANSMITTANCE_MIN)
_LOG_HALF = math.log(0.5)
DEFAULT_CHUNK_ELEMS = 1 << 18  # alpha values per chunk: ~1 MiB float32 per temporary


def _csr(crow: Tensor, col: Tensor, values: Tensor, shape) -> Tensor:
    with warnings.catch_warnings():  # "sparse CSR support is in beta": known, not actionable
        warnings.simplefilter("ignore", UserWarning)
        return torch.sparse_csr_tensor(crow, col, values, size=shape, check_invariants=False)


@dataclass
class _Chunk:
    """Rows [r0, r1) covering whole tiles [t0, t1), with chunk-local index tensors."""

    r0: int
    r1: int
    t0: int
    t1: int
    seg_start: Tensor  # [n] chunk-local first row of each row's tile
    seg_last: Tensor  # [n] chunk-local last row of each row's tile
    tile_local: Tensor  # [n] tile index - t0
    x0: Tensor  # [n] tile left edge (pixels)
    y0: Tensor  # [n] tile top edge (pixels)


def plan_chunks(isects: TileIntersections, chunk_elems: int = DEFAULT_CHUNK_ELEMS) -> List[_Chunk]:
    """Split the sorted intersections into runs of whole tiles of about ``chunk_elems`` values."""
    b = isects.tile_size
    rows_per_chunk = max(1, chunk_elems // isects.slots_per_tile)
    offsets = isects.tile_offsets
    total = int(offsets[-1])
    if total == 0:
        return []
    # Tile boundaries closest below multiples of rows_per_chunk (a tile larger than a chunk is
    # a chunk of its own).
    cuts = {0, offsets.numel() - 1}
    if total > rows_per_chunk:
        targets = torch.arange(rows_per_chunk, total, rows_per_chunk, device=offsets.device)
        cuts.update((torch.searchsorted(offsets, targets, right=True) - 1).tolist())
    cuts = sorted(cuts)
    local = isects.tile_ids % (isects.tiles_x * isects.tiles_y)
    x0_all = ((local % isects.tiles_x) * b).float()
    y0_all = (torch.div(local, isects.tiles_x, rounding_mode="floor") * b).float()
    chunks = []
    offs = offsets.tolist()
    for t0, t1 in zip(cuts[:-1], cuts[1:]):
        r0, r1 = offs[t0], offs[t1]
        if r1 == r0:
            continue
        tid = isects.tile_ids[r0:r1]
        chunks.append(
            _Chunk(
                r0=r0, r1=r1, t0=t0, t1=t1,
                seg_start=offsets[tid] - r0, seg_last=offsets[tid + 1] - 1 - r0,
                tile_local=tid - t0, x0=x0_all[r0:r1], y0=y0_all[r0:r1],
            )
        )  # fmt: skip
    return chunks


def _offsets(b: int, device, dtype) -> Tuple[Tensor, Tensor]:
    j = torch.arange(b * b, device=device)
    return (j % b).to(dtype) + 0.5, torch.div(j, b, rounding_mode="floor").to(dtype) + 0.5


def _deltas(ch: _Chunk, gid: Tensor, means2d: Tensor, ox: Tensor, oy: Tensor, isects):
    """Mean minus sample position, [n, S] each (x wrapped when the grid is periodic)."""
    m = means2d[gid]
    if isects.slot_x is None:
        dx = (m[:, 0] - ch.x0.to(m.dtype))[:, None] - ox[None, :]
        dy = (m[:, 1] - ch.y0.to(m.dtype))[:, None] - oy[None, :]
        return dx, dy
    tiles = ch.tile_local + ch.t0
    dx = m[:, 0:1] - isects.slot_x[tiles].to(m.dtype)
    dy = m[:, 1:2] - isects.slot_y[tiles].to(m.dtype)
    if isects.period_x is not None:
        period = isects.period_x
        dx = dx - period * torch.round(dx / period)
    return dx, dy


def _sigma(dx: Tensor, dy: Tensor, con: Tensor) -> Tensor:
    sig = dx * dx
    sig.mul_(0.5 * con[:, 0:1])
    tmp = dy * dy
    sig.addcmul_(tmp, 0.5 * con[:, 2:3])
    torch.mul(dx, dy, out=tmp)
    sig.addcmul_(tmp, con[:, 1:2])
    return sig


def _pixel_csr(ch: _Chunk, counts: Tensor, bb: int, values: Tensor, cols: Tensor):
    """CSR (rows = the chunk's tile pixels, entries in depth order) of [n, bb] values."""
    n = ch.r1 - ch.r0
    device = values.device
    j = torch.arange(bb, device=device)
    cnt = counts[ch.t0 : ch.t1]
    start = torch.cumsum(cnt, 0) - cnt
    crow = torch.empty((ch.t1 - ch.t0) * bb + 1, dtype=torch.int64, device=device)
    crow[:-1] = (bb * start[:, None] + j[None, :] * cnt[:, None]).reshape(-1)
    crow[-1] = n * bb
    rows = torch.arange(n, device=device)
    pos = (bb * ch.seg_start + (rows - ch.seg_start))[:, None] + j[None, :] * cnt[ch.tile_local][:, None]
    pos = pos.reshape(-1)
    vals = torch.empty(n * bb, dtype=values.dtype, device=device).scatter_(0, pos, values.reshape(-1))
    col = torch.empty(n * bb, dtype=torch.int64, device=device).scatter_(
        0, pos, cols[:, None].expand(n, bb).reshape(-1)
    )
    return crow, col, vals, pos


class TileComposite(torch.autograd.Function):
    """Composite all tiles; returns (pixel sums [T*B*B, D'], crossing counts [T, B*B])."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, isects, chunks):
        # means2d: [G, 2]; conics: [G, 3]; opacities: [G]; feats: [G, D'] (G = C*N)
        b = isects.tile_size
        bb = isects.slots_per_tile
        device, dtype = means2d.device, means2d.dtype
        n_isect = isects.gaussian_ids.numel()
        out = torch.zeros(isects.num_tiles * bb, feats.shape[1], device=device, dtype=dtype)
        crossing = torch.zeros(isects.num_tiles, bb, device=device, dtype=torch.int64)
        alpha_all = torch.empty(n_isect, bb, device=device, dtype=dtype)
        trans_all = torch.empty(n_isect, bb, device=device, dtype=dtype)
        counts = isects.tile_offsets[1:] - isects.tile_offsets[:-1]
        ox, oy = _offsets(b, device, dtype)
        for ch in chunks:
            gid = isects.gaussian_ids[ch.r0 : ch.r1]
            dx, dy = _deltas(ch, gid, means2d, ox, oy, isects)
            sig = _sigma(dx, dy, conics[gid])
            alpha = sig.clamp_min_(0.0).neg_().exp_().mul_(opacities[gid][:, None])
            alpha.clamp_max_(ALPHA_MAX)
            alpha.masked_fill_(alpha < ALPHA_MIN, 0.0)
            if isects.slot_valid is not None:  # padding slots of irregular (lidar) tiles
                alpha.mul_(isects.slot_valid[ch.tile_local + ch.t0])
            log_t = torch.log1p(-alpha)
            cum = torch.cumsum(log_t, 0, dtype=torch.float64)
            cum_pad = torch.cat([cum.new_zeros(1, bb), cum])
            incl = cum.sub_(cum_pad[ch.seg_start])  # log T after this Gaussian
            cross = incl > _LOG_HALF
            crossing[ch.t0 : ch.t1].index_add_(0, ch.tile_local, cross.to(torch.int64))
            alive = incl > _LOG_T_MIN
            trans = incl.sub_(log_t).exp_().to(dtype).mul_(alive)
            w = alpha * trans
            crow, col, vals, _ = _pixel_csr(ch, counts, bb, w, gid)
            mat = _csr(crow, col, vals, ((ch.t1 - ch.t0) * bb, feats.shape[0]))
            out[ch.t0 * bb : ch.t1 * bb] = mat @ feats
            alpha_all[ch.r0 : ch.r1] = alpha
            trans_all[ch.r0 : ch.r1] = trans
        ctx.isects, ctx.chunks = isects, chunks
        ctx.save_for_backward(means2d, conics, opacities, feats, alpha_all, trans_all)
        ctx.mark_non_differentiable(crossing)
        return out, crossing

    @staticmethod
    def backward(ctx, grad_out, _grad_crossing):
        means2d, conics, opacities, feats, alpha_all, trans_all = ctx.saved_tensors
        isects: TileIntersections = ctx.isects
        b = isects.tile_size
        bb = isects.slots_per_tile
        device, dtype = means2d.device, means2d.dtype
        grad_out = grad_out.contiguous()
        g_means = torch.zeros_like(means2d)
        g_conics = torch.zeros_like(conics)
        g_opac = torch.zeros_like(opacities)
        g_feats = torch.zeros_like(feats)
        counts = isects.tile_offsets[1:] - isects.tile_offsets[:-1]
        ox, oy = _offsets(b, device, dtype)
        j = torch.arange(bb, device=device)
        for ch in ctx.chunks:
            n = ch.r1 - ch.r0
            gid = isects.gaussian_ids[ch.r0 : ch.r1]
            alpha = alpha_all[ch.r0 : ch.r1]
            trans = trans_all[ch.r0 : ch.r1]
            w = alpha * trans
            g_pix = grad_out[ch.t0 * bb : ch.t1 * bb]
            # dL/dw: per entry dot(g_pix[pixel], feats[gid]) on the CSR pattern, back to [n, bb].
            crow, col, vals, pos = _pixel_csr(ch, counts, bb, w, gid)
            shape = ((ch.t1 - ch.t0) * bb, feats.shape[0])
            pattern = _csr(crow, col, torch.zeros_like(vals), shape)
            sampled = torch.sparse.sampled_addmm(pattern, g_pix, feats.t(), beta=0.0)
            grad_w = sampled.values()[pos].reshape(n, bb)
            if ctx.needs_input_grad[3]:
                # dL/dfeats[g] = sum over its entries of w * g_pix: natural (row-major) CSR.
                crow_t = torch.arange(n + 1, device=device) * bb
                col_t = (ch.tile_local[:, None] * bb + j[None, :]).reshape(-1)
                mat_t = _csr(crow_t, col_t, w.reshape(-1), (n, shape[0]))
                g_feats.index_add_(0, gid, mat_t @ g_pix)
            gw = (grad_w * w).double()
            cum = gw.cumsum_(0)
            suffix = cum[ch.seg_last].sub_(cum)  # sum of g*w strictly behind each row
            active = (alpha > 0) & (alpha < ALPHA_MAX) & (trans > 0)
            d_alpha = suffix.div_((1.0 - alpha).double()).to(dtype).neg_().addcmul_(grad_w, trans)
            d_alpha.mul_(active)
            # alpha = o exp(-sigma): p = dL/dalpha * alpha; dL/dsigma = -p; dL/do = sum p / o.
            p = d_alpha.mul_(alpha)
            op = opacities[gid]
            g_opac.index_add_(0, gid, p.sum(1) / op.clamp_min(1e-30))
            dx, dy = _deltas(ch, gid, means2d, ox, oy, isects)
            q_dx = p * dx
            q_dy = p * dy
            s_x, s_y = q_dx.sum(1), q_dy.sum(1)
            s_xx, s_xy, s_yy = (q_dx * dx).sum(1), (q_dx * dy).sum(1), (q_dy * dy).sum(1)
            con = conics[gid]
            a_, b_, c_ = con.unbind(1)
            gm = torch.stack([-(a_ * s_x + b_ * s_y), -(b_ * s_x + c_ * s_y)], 1)
            gc = torch.stack([-0.5 * s_xx, -s_xy, -0.5 * s_yy], 1)
            g_means.index_add_(0, gid, gm)
            g_conics.index_add_(0, gid, gc)
        return g_means, g_conics, g_opac, g_feats, None, None
