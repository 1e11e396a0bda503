"""Tile compositing on CUDA as Triton kernels: the contract of
:class:`~idsplat_ns.render.tile_composite.TileComposite`, one GPU program per tile.

Why Triton: the torch compositor runs a tile group's depth blocks as dozens of tensor ops each,
with host synchronisations between blocks; on a GPU a lidar batch is then kernel launches, not
arithmetic (0.21 s of a 0.37 s paper-configuration step on an H200, two thirds in the backward
pass). Triton ships with CUDA builds of torch, so nothing is compiled at install time.

The kernels follow the rules of the compiled CPU loops (:mod:`idsplat_ns.render.compiled_composite`):
a program holds one tile's samples (lanes) and walks its rows front to back ``BLOCK_R`` at a
time: the chunk's alphas, ``log(1 - alpha)`` and its running sum along the rows (``tl.cumsum``)
give the transmittance before each row, the early stop and the crossing count; the feature sums
are one ``tl.dot`` (IEEE float32). The loop ends once every live lane has ``T <= 1e-4``; kept for
the backward pass are each lane's final transmittance and first dropped row. The backward
program runs the chunks from the back, recovering ``T`` before each row from ``T`` after the chunk
and a reversed running sum of ``log(1 - alpha)`` (gsplat's division by ``1 - alpha``, as sums),
with ``S = sum_{m > k} g_m w_m`` in float64: ``dL/de_k = S alpha_k / (1 - alpha_k) - g_k w_k``
(zero at the 0.999 clamp), minus ``alpha_k g_cutoff`` for rows in front of the cut-off. Each row
belongs to one tile, so its coefficient gradient has one writer; feature gradients gather from
many tiles by atomic adds.

The exponent ``coeffs[row] . basis[:, s]`` is summed in float64 (its terms cancel, see
:mod:`~idsplat_ns.render.tile_composite`), everything else per sample in float32. Features must
be float32. On CPU tensors the kernels run only under Triton's interpreter
(``TRITON_INTERPRET=1``, set before this module is imported): slow, for the tests.
"""

from __future__ import annotations

import math

import torch
import triton
import triton.language as tl

from .reference import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN

_E_CLAMP = tl.constexpr(-math.log(ALPHA_MAX))  # exponents at or below it give the 0.999 clamp
_E_MAX = tl.constexpr(-math.log(ALPHA_MIN) + 1.0)  # alpha is below 1/255 long before this
_ALPHA_MIN = tl.constexpr(ALPHA_MIN)
_LOG_T_MIN = tl.constexpr(math.log(TRANSMITTANCE_MIN))
_LOG_HALF = tl.constexpr(math.log(0.5))


@triton.jit
def _chunk_alpha(coeffs_ptr, rows, row_ok, b1, b2, b3, b4, b5, live):
    """Exponent [R, S] of rows ``rows`` [R] at the tile's samples (a float64 sum, rounded once to
    float32) and alpha: ``exp(-e)`` clamped at 0.999, zero below 1/255, on rows not ``row_ok``
    and on lanes where ``live`` [S] is 0."""
    c = coeffs_ptr + rows * 6
    k0 = tl.load(c, mask=row_ok, other=0.0)[:, None]
    k1 = tl.load(c + 1, mask=row_ok, other=0.0)[:, None]
    k2 = tl.load(c + 2, mask=row_ok, other=0.0)[:, None]
    k3 = tl.load(c + 3, mask=row_ok, other=0.0)[:, None]
    k4 = tl.load(c + 4, mask=row_ok, other=0.0)[:, None]
    k5 = tl.load(c + 5, mask=row_ok, other=0.0)[:, None]
    e = (k0 + k1 * b1[None, :] + k2 * b2[None, :] + k3 * b3[None, :] + k4 * b4[None, :] + k5 * b5[None, :]).to(tl.float32)
    al = tl.exp(-tl.minimum(tl.maximum(e, _E_CLAMP), _E_MAX))
    al = tl.where((al >= _ALPHA_MIN) & row_ok[:, None], al, 0.0) * live[None, :]
    return e, al


@triton.jit
def _tile_samples(basis_ptr, basis_tile_stride, valid_ptr, t, s, slots, HAS_VALID: tl.constexpr):
    """Tile ``t``'s basis rows 1..5 (float64, [BLOCK_S]) and its live lanes (float32 1/0)."""
    smask = s < slots
    b = basis_ptr + t * basis_tile_stride + s
    b1 = tl.load(b + slots, mask=smask, other=0.0)
    b2 = tl.load(b + 2 * slots, mask=smask, other=0.0)
    b3 = tl.load(b + 3 * slots, mask=smask, other=0.0)
    b4 = tl.load(b + 4 * slots, mask=smask, other=0.0)
    b5 = tl.load(b + 5 * slots, mask=smask, other=0.0)
    if HAS_VALID:
        live = tl.load(valid_ptr + t * slots + s, mask=smask, other=0.0)
    else:
        live = smask.to(tl.float32)
    return b1, b2, b3, b4, b5, live


@triton.jit
def _forward_kernel(
    coeffs_ptr, basis_ptr, basis_tile_stride, feats_ptr, gid_ptr, offsets_ptr, valid_ptr, cutoff_ptr, gdepth_ptr,
    out_ptr, crossing_ptr, before_ptr, stop_ptr, t_final_ptr, slots, d,
    HAS_VALID: tl.constexpr, HAS_CUTOFF: tl.constexpr, BLOCK_R: tl.constexpr, BLOCK_S: tl.constexpr,
    BLOCK_D: tl.constexpr,
):  # fmt: skip
    """Composite tile ``program_id``, BLOCK_R rows at a time: ``out`` [T, S, D] sums, ``crossing``
    [T, S] rows after which ``T > 0.5``, ``before`` [T, S] (with a cut-off), ``stop`` [T, S] first
    dropped row relative to the tile's start (else its row count; 0 on padding lanes) and
    ``t_final`` [T, S] (T after the composited rows)."""
    t = tl.program_id(0).to(tl.int64)
    s = tl.arange(0, BLOCK_S)
    j = tl.arange(0, BLOCK_D)
    q = tl.arange(0, BLOCK_R)
    smask, jmask = s < slots, j < d
    start = tl.load(offsets_ptr + t)
    end = tl.load(offsets_ptr + t + 1)
    b1, b2, b3, b4, b5, live = _tile_samples(basis_ptr, basis_tile_stride, valid_ptr, t, s, slots, HAS_VALID)
    log_t = tl.zeros([BLOCK_S], tl.float32)  # log T after the rows so far (dropped rows included)
    log_t_kept = tl.zeros([BLOCK_S], tl.float32)  # log T after the composited rows
    cross = tl.zeros([BLOCK_S], tl.int32)
    stop = tl.where(live > 0.0, end - start, 0)
    acc = tl.zeros([BLOCK_D, BLOCK_S], tl.float32)
    before = tl.zeros([BLOCK_S], tl.float32)
    if HAS_CUTOFF:
        cut = tl.load(cutoff_ptr + t * slots + s, mask=smask, other=-float("inf"))
    r0 = start
    n_live = tl.sum((live > 0.0).to(tl.int32))
    while (r0 < end) & (n_live > 0):
        rows = r0 + q
        row_ok = rows < end
        e, al = _chunk_alpha(coeffs_ptr, rows, row_ok, b1, b2, b3, b4, b5, live)
        log1m = tl.log(1.0 - al)
        incl = log_t[None, :] + tl.cumsum(log1m, axis=0)  # log T after each row
        # The row that would bring T to <= 1e-4 and all behind it are dropped (gsplat's early stop).
        keep = incl > _LOG_T_MIN
        w = tl.where(keep, al * tl.exp(incl - log1m), 0.0)
        cross += tl.sum((row_ok[:, None] & (incl > _LOG_HALF)).to(tl.int32), axis=0)
        dropped = row_ok[:, None] & (live[None, :] > 0.0) & (incl <= _LOG_T_MIN)
        stop = tl.minimum(stop, tl.min(tl.where(dropped, rows[:, None] - start, end - start), axis=0))
        g = tl.load(gid_ptr + rows, mask=row_ok, other=0)
        f = tl.load(feats_ptr + g[:, None] * d + j[None, :], mask=row_ok[:, None] & jmask[None, :], other=0.0)
        acc += tl.dot(tl.trans(f), w, input_precision="ieee")
        if HAS_CUTOFF:
            dg = tl.load(gdepth_ptr + g, mask=row_ok, other=float("inf"))
            before += tl.sum(tl.where((dg[:, None] < cut[None, :]) & (w > 0.0), al, 0.0), axis=0)
        log_t_kept += tl.sum(tl.where(keep, log1m, 0.0), axis=0)
        log_t += tl.sum(log1m, axis=0)
        r0 += BLOCK_R
        n_live = tl.sum(((live > 0.0) & (log_t > _LOG_T_MIN)).to(tl.int32))
    row = t * slots + s
    tl.store(out_ptr + row[None, :] * d + j[:, None], acc, mask=smask[None, :] & jmask[:, None])
    tl.store(crossing_ptr + row, cross, mask=smask)
    tl.store(stop_ptr + row, stop, mask=smask)
    tl.store(t_final_ptr + row, tl.exp(log_t_kept), mask=smask)
    if HAS_CUTOFF:
        tl.store(before_ptr + row, before, mask=smask)


@triton.jit
def _backward_kernel(
    coeffs_ptr, basis_ptr, basis_tile_stride, feats_ptr, gid_ptr, offsets_ptr, valid_ptr, cutoff_ptr, gdepth_ptr,
    stop_ptr, t_final_ptr, g_out_ptr, g_before_ptr, g_coeffs_ptr, g_feats_ptr, slots, d,
    HAS_VALID: tl.constexpr, HAS_CUTOFF: tl.constexpr, BLOCK_R: tl.constexpr, BLOCK_S: tl.constexpr,
    BLOCK_D: tl.constexpr,
):  # fmt: skip
    """Gradients of tile ``program_id``'s rows, BLOCK_R rows at a time from the back: ``g_coeffs``
    [I, 6] (float64, one writer per row) and atomic adds into ``g_feats`` [G, D], from ``g_out``
    [T, S, D] and ``g_before`` [T, S]."""
    t = tl.program_id(0).to(tl.int64)
    s = tl.arange(0, BLOCK_S)
    j = tl.arange(0, BLOCK_D)
    q = tl.arange(0, BLOCK_R)
    smask, jmask = s < slots, j < d
    start = tl.load(offsets_ptr + t)
    b1, b2, b3, b4, b5, live = _tile_samples(basis_ptr, basis_tile_stride, valid_ptr, t, s, slots, HAS_VALID)
    row = t * slots + s
    trans = tl.load(t_final_ptr + row, mask=smask, other=1.0)  # T after the chunk being done
    stop = tl.load(stop_ptr + row, mask=smask, other=0)
    last = tl.max(stop)
    go = tl.load(g_out_ptr + row[None, :] * d + j[:, None], mask=smask[None, :] & jmask[:, None], other=0.0)  # [D, S]
    if HAS_CUTOFF:
        cut = tl.load(cutoff_ptr + row, mask=smask, other=-float("inf"))
        gb = tl.load(g_before_ptr + row, mask=smask, other=0.0)
    behind = tl.zeros([BLOCK_S], tl.float64)  # sum of g w over the rows behind the chunk
    for c in range(0, tl.cdiv(last, BLOCK_R)):
        rank = (tl.cdiv(last, BLOCK_R) - 1 - c) * BLOCK_R + q
        rows = start + rank
        row_ok = rank < last
        e, al = _chunk_alpha(coeffs_ptr, rows, row_ok, b1, b2, b3, b4, b5, live)
        al = tl.where(rank[:, None] < stop[None, :], al, 0.0)  # composited rows only
        log1m = tl.log(1.0 - al)
        # T before each row from T after the chunk (gsplat's division by 1 - alpha, as sums of logs).
        w = al * trans[None, :] * tl.exp(-tl.cumsum(log1m, axis=0, reverse=True))
        g = tl.load(gid_ptr + rows, mask=row_ok, other=0)
        f = tl.load(feats_ptr + g[:, None] * d + j[None, :], mask=row_ok[:, None] & jmask[None, :], other=0.0)
        gw = (tl.dot(f, go, input_precision="ieee") * w).to(tl.float64)  # g w, g = dL/dw
        any_w = row_ok & (tl.sum(w, axis=1) > 0.0)  # rows that composite nothing here add nothing
        g_f = tl.dot(w, tl.trans(go), input_precision="ieee")  # [R, D]
        tl.atomic_add(g_feats_ptr + g[:, None] * d + j[None, :], g_f, mask=any_w[:, None] & jmask[None, :])
        # S_k = sum_{m > k} g_m w_m (float64); dL/de_k = S_k alpha_k / (1 - alpha_k) - g_k w_k.
        p = (behind[None, :] + tl.cumsum(gw, axis=0, reverse=True) - gw) * (al / (1.0 - al)).to(tl.float64) - gw
        if HAS_CUTOFF:  # line of sight: dL/dalpha += g on composited rows in front of the cut-off
            dg = tl.load(gdepth_ptr + g, mask=row_ok, other=float("inf"))
            p -= tl.where((dg[:, None] < cut[None, :]) & (w > 0.0), al * gb[None, :], 0.0).to(tl.float64)
        p = tl.where((e > _E_CLAMP) & (al > 0.0), p, 0.0)  # no gradient at the clamp or where skipped
        behind += tl.sum(gw, axis=0)
        trans = trans * tl.exp(-tl.sum(log1m, axis=0))
        out = g_coeffs_ptr + rows * 6
        tl.store(out, tl.sum(p, axis=1), mask=row_ok)
        tl.store(out + 1, tl.sum(p * b1[None, :], axis=1), mask=row_ok)
        tl.store(out + 2, tl.sum(p * b2[None, :], axis=1), mask=row_ok)
        tl.store(out + 3, tl.sum(p * b3[None, :], axis=1), mask=row_ok)
        tl.store(out + 4, tl.sum(p * b4[None, :], axis=1), mask=row_ok)
        tl.store(out + 5, tl.sum(p * b5[None, :], axis=1), mask=row_ok)


def _launch_shape(slots: int, d: int) -> dict:
    # tl.dot needs every dimension >= 16: lanes and features are padded to that.
    block_s = max(16, triton.next_power_of_2(max(slots, 1)))
    block_d = max(16, triton.next_power_of_2(max(d, 1)))
    block_r = max(16, min(64, 2048 // block_s))  # rows a chunk: ~2048 (row, lane) values
    return dict(BLOCK_R=block_r, BLOCK_S=block_s, BLOCK_D=block_d, num_warps=4)


class TritonTileComposite(torch.autograd.Function):
    """:class:`~idsplat_ns.render.tile_composite.TileComposite` computed by Triton kernels: the
    same inputs (``coeffs`` [I, 6] float64, ``feats`` [G, D] float32, the
    :class:`~idsplat_ns.render.tile_composite.CompositePlan`), outputs and gradients (to float
    rounding)."""

    @staticmethod
    def forward(ctx, coeffs, feats, plan):
        device = feats.device
        n_tiles, slots, d = plan.num_tiles, plan.slots, feats.shape[1]
        basis = plan.basis.to(torch.float64).contiguous()
        has_valid, has_cutoff = plan.slot_valid is not None, plan.cutoff_depths is not None
        none = torch.empty(0, device=device)
        # The plan as the kernels read it, the same in the forward and the backward pass.
        inputs = (
            coeffs.detach().to(torch.float64).contiguous(), basis, 0 if basis.dim() == 2 else 6 * slots,
            feats.detach().contiguous(), plan.gaussian_ids.contiguous(), plan.tile_offsets.contiguous(),
            plan.slot_valid.to(torch.float32).contiguous() if has_valid else none,
            plan.cutoff_depths.to(torch.float32).contiguous() if has_cutoff else none,
            plan.gaussian_depths.detach().to(torch.float32).contiguous() if has_cutoff else none,
        )  # fmt: skip
        out = torch.empty(n_tiles * slots, d, device=device, dtype=torch.float32)
        crossing = torch.empty(n_tiles, slots, device=device, dtype=torch.int32)
        before = torch.zeros(n_tiles * slots if has_cutoff else 0, device=device, dtype=torch.float32)
        stop = torch.empty(n_tiles, slots, device=device, dtype=torch.int64)
        t_final = torch.empty(n_tiles, slots, device=device, dtype=torch.float32)
        if n_tiles > 0:
            _forward_kernel[(n_tiles,)](*inputs, out, crossing, before, stop, t_final, slots, d, HAS_VALID=has_valid,
                                        HAS_CUTOFF=has_cutoff, **_launch_shape(slots, d))  # fmt: skip
        ctx.inputs, ctx.plan_flags = inputs, (has_valid, has_cutoff, n_tiles, slots, d)
        ctx.coeffs_dtype = coeffs.dtype
        ctx.save_for_backward(stop, t_final)
        crossing = crossing.long()
        ctx.mark_non_differentiable(crossing)
        if has_cutoff:
            return out, crossing, before
        return out, crossing

    @staticmethod
    def backward(ctx, grad_out, _grad_crossing, *grad_before_cutoff):
        stop, t_final = ctx.saved_tensors
        coeffs, feats = ctx.inputs[0], ctx.inputs[3]
        has_valid, has_cutoff, n_tiles, slots, d = ctx.plan_flags
        device = grad_out.device
        g_before = torch.zeros(n_tiles * slots if has_cutoff else 0, device=device, dtype=torch.float32)
        if has_cutoff and grad_before_cutoff and grad_before_cutoff[0] is not None:
            g_before = grad_before_cutoff[0].to(torch.float32).contiguous()
        g_coeffs = torch.zeros_like(coeffs)
        g_feats = torch.zeros_like(feats)
        if n_tiles > 0:
            _backward_kernel[(n_tiles,)](*ctx.inputs, stop, t_final, grad_out.to(torch.float32).contiguous(), g_before,
                                         g_coeffs, g_feats, slots, d, HAS_VALID=has_valid, HAS_CUTOFF=has_cutoff,
                                         **_launch_shape(slots, d))  # fmt: skip
        return g_coeffs.to(ctx.coeffs_dtype), g_feats, None
