"""Fused tile compositing with a hand-written backward, in blocks of depth ranks.

Each (tile, Gaussian) intersection carries the six coefficients of its exponent as a quadratic
polynomial of the sample offset ``(ex, ey)`` from the tile centre:

``-log(alpha_unclamped) = k0 + k1 ex + k2 ey + k3 ex^2 + k4 ex ey + k5 ey^2``

(:func:`quadratic_coefficients`, or :class:`TileCoefficients` for gathered rows; ``k0`` includes
``-log(opacity)``). The exponent of every (intersection, sample) pair is then one matrix product
``coeffs @ basis`` with the fixed ``[6, S]`` monomial basis of the tile's samples, and the
gradient of the coefficients is the product back, ``p @ basis^T``. Both products are float64:
the polynomial's terms are up to ~1e2 and cancel near the Gaussian, so float32 there would
dominate the error of the whole rasterizer (everything else per sample is float32).

Tiles are processed in groups of similar list length (about ``block_elems / (32 S)`` tiles),
each group in blocks of depth ranks: a block holds rows ``[start, start + L)`` of every tile of
the group that still has rows there, padded to ``L`` (a sentinel row with zero alpha), so it is a
dense ``[tiles, L, S]`` batch: transmittance is a plain ``cumsum`` of ``log(1 - alpha)`` along L
(float32; each block starts from the carried log-transmittance), features are summed by a
batched matrix product. A tile whose samples have all reached ``T <= 1e-4`` (gsplat's early
stop) leaves the loop, so the Gaussians behind saturated tiles are never evaluated. Blocks of
about ``block_elems`` values keep the temporaries in cache; only alpha and the weights of each
block are kept for the backward pass.

Backward, for weights ``w_k = alpha_k T_k`` along one sample's list with upstream ``g_k``:
``p_k = dL/d(exponent_k) = S_k alpha_k / (1 - alpha_k) - g_k w_k`` (zero where alpha is clamped)
with ``S_k = sum_{m > k} g_m w_m``, computed block by block from the back with the suffix sum
carried per sample. Rules: :mod:`idsplat_ns.render.reference`.

Optional line-of-sight output (lidar): with ``plan.cutoff_depths`` [T, S] and
``plan.gaussian_depths`` [G], a third output holds per sample the sum of the alphas of the rows
it composites (``w > 0``: alpha >= 1/255, before the early stop) whose depth is below the sample's
cut-off (SplatAD's ``alpha_sum_until_points``). Its gradient adds ``g`` to ``dL/dalpha`` of
those rows (the depth test is a step). Without a cut-off nothing of this runs.
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
# On a GPU each block costs kernel launches from Python, not cache misses: 2^24 composites a
# 1920x1280 image with 1M Gaussians 22x faster than 2^18 on an H200 (docs/reports/2026-11-27-gpu-rasterizers.md).
CUDA_BLOCK_ELEMS = 1 << 24


def default_block_elems(device: torch.device) -> int:
    """Block size of the compositor on ``device``: cache-sized on the CPU, larger on CUDA."""
    return CUDA_BLOCK_ELEMS if torch.device(device).type == "cuda" else DEFAULT_BLOCK_ELEMS


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


class TileCoefficients(torch.autograd.Function):
    """:func:`quadratic_coefficients` of gathered rows, with a hand-written backward.

    ``params`` [I, 6] holds (mean x, mean y, a, b, c, opacity) per intersection (any float
    dtype), ``cx``, ``cy`` [I] the tile centres (float64, not differentiated). Returns the
    float64 coefficients [I, 6]; the gradient comes back as one [I, 6] tensor in the dtype of
    ``params`` (autograd through the column slices would allocate and zero an [I, 6] gradient
    per slice).
    """

    @staticmethod
    def forward(ctx, params, cx, cy):
        p = params.detach().to(torch.float64)
        dx, dy = p[:, 0] - cx, p[:, 1] - cy
        a, b, c = p[:, 2], p[:, 3], p[:, 4]
        o = p[:, 5]
        ctx.save_for_backward(dx, dy, a, b, c, o)
        ctx.params_dtype = params.dtype
        return quadratic_coefficients(dx, dy, p[:, 2:5], o)

    @staticmethod
    def backward(ctx, grad):
        dx, dy, a, b, c, o = ctx.saved_tensors
        g0, g1, g2, g3, g4, g5 = grad.unbind(-1)
        u, v = g0 * dx - g1, g0 * dy - g2  # d/d(dx), d/d(dy) share these
        g_o = torch.where(o > 1e-30, -g0 / o.clamp_min(1e-30), 0.0)
        g_params = torch.stack(
            [a * u + b * v, b * u + c * v, 0.5 * (g0 * dx - 2 * g1) * dx + 0.5 * g3,
             g0 * dx * dy - g1 * dy - g2 * dx + g4, 0.5 * (g0 * dy - 2 * g2) * dy + 0.5 * g5, g_o],
            dim=-1,
        )  # fmt: skip
        return g_params.to(ctx.params_dtype), None, None


@dataclass
class CompositePlan:
    """What :class:`TileComposite` needs besides the differentiable inputs."""

    tile_offsets: Tensor  # [T + 1] int64 start of each tile's depth-sorted run of intersections
    gaussian_ids: Tensor  # [I] int64 row of ``feats`` for each intersection
    basis: Tensor  # [6, S] shared by all tiles, or [T, 6, S] per tile (irregular samples), float64
    slot_valid: Optional[Tensor] = None  # [T, S] float 1/0, 0 for padding samples (lidar)
    block_elems: Optional[int] = None  # target (row, sample) values per block (None: the device's default)
    cutoff_depths: Optional[Tensor] = None  # [T, S] line-of-sight cut-off per sample (-inf: none)
    gaussian_depths: Optional[Tensor] = None  # [G] depth of each feature row, for the cut-off test

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
    weights: Tensor  # [Ta, L, S] alpha times the transmittance before the row (0 once dropped)
    maybe_clamped: bool  # some alpha may sit at the 0.999 clamp (then masked in the backward)


class _Workspace:
    """Reusable float buffers: a fresh multi-megabyte tensor costs a page-faulting first touch on
    CPU (about as much as two elementwise passes), so block temporaries share storage."""

    def __init__(self, device, dtype):
        self.device, self.dtype, self.buffers = device, dtype, {}

    def get(self, name: str, shape, dtype: Optional[torch.dtype] = None) -> Tensor:
        n, dtype = math.prod(shape), dtype or self.dtype
        buf = self.buffers.get(name)
        if buf is None or buf.numel() < n or buf.dtype != dtype:
            buf = torch.empty(n, device=self.device, dtype=dtype)
            self.buffers[name] = buf
        return buf[:n].view(shape)



def _in_front(plan: CompositePlan, gid_ext: Tensor, tiles: Tensor, rows: Tensor, w: Tensor) -> Tensor:
    """[Ta, L, S] bool: composited rows (``w > 0``) in front of the sample's cut-off depth."""
    ta, lb = rows.shape
    depth = plan.gaussian_depths.index_select(0, gid_ext.index_select(0, rows.reshape(-1))).view(ta, lb, 1)
    return (depth < plan.cutoff_depths.index_select(0, tiles)[:, None, :]) & (w > 0)


def _below(value: float, dtype: torch.dtype) -> float:
    """The largest number of ``dtype`` below ``value``: ``x > _below(v)`` is ``x >= v`` there."""
    v = torch.tensor(value, dtype=dtype)
    return torch.nextafter(v, torch.tensor(-math.inf, dtype=dtype)).item()


def _log_alpha(
    coeffs: Tensor,  # [Ta, L, 6]
    neg_basis: Tensor,  # [6, S] or [T, 6, S], the negated basis
    tiles: Tensor,  # [Ta]
    out: Tensor,  # [Ta * L, S] buffer
) -> Tensor:
    """Unclamped ``log alpha`` (the negated exponent) of every (row, sample), written to ``out``."""
    if neg_basis.dim() == 2:
        return torch.mm(coeffs.reshape(-1, 6), neg_basis, out=out)
    ta, lb, _ = coeffs.shape
    return torch.bmm(coeffs, neg_basis.index_select(0, tiles), out=out.view(ta, lb, -1))


# Skipped samples and dropped rows become exact zeros by a threshold pass *after* exp: exp of
# -inf or of underflowing arguments takes a slow path (3-7x) on CPU, so the arguments are kept
# finite and well above the underflow range.
# A block whose largest log alpha is below this has no alpha at the clamp (a margin: the
# backward masks exactly alpha >= _ALPHA_CLAMPED; this flag only lets it skip the mask).
_CLAMP_FLAG_ABOVE = -_T_CLAMP - 1e-4


@dataclass
class _ForwardState:
    """What every block of one forward pass shares."""

    plan: CompositePlan
    coeffs: Tensor  # [I + 1, 6] float64, the coefficients plus the sentinel row
    neg_basis: Tensor  # [6, S] or [T, 6, S] float64, -basis (the product is then log alpha)
    feats: Tensor  # [G, D]
    gid_ext: Tensor  # [I + 1] feature row of each intersection (sentinel: 0)
    counts: Tensor  # [T] rows per tile
    ranks: Tensor  # [max rows] 0, 1, 2, ...
    out: Tensor  # [T, D, S] feature sums
    crossing: Tensor  # [T, S] int32
    before_cutoff: Optional[Tensor]  # [T, S] summed alpha in front of the cut-off (when asked)
    work: _Workspace  # working dtype buffers
    work64: _Workspace  # float64 buffers
    keep_alpha_above: float  # largest value below 1/255 in the working dtype


def _forward_block(st: _ForwardState, tiles: Tensor, start: int, carry: Tensor, lb: int):
    """Composite rows ``[start, start + lb)`` of ``tiles`` [Ta] after log T ``carry`` [Ta, S].

    Returns the :class:`_Block` and the log T after it [Ta, S]."""
    plan, feats = st.plan, st.feats
    ta, slots, n_isect, d = tiles.numel(), plan.slots, st.coeffs.shape[0] - 1, feats.shape[1]
    dtype = feats.dtype
    left = st.counts[tiles] - start
    rows = plan.tile_offsets[tiles][:, None] + start + st.ranks[None, :lb]
    rows = torch.where(st.ranks[None, :lb] < left[:, None], rows, n_isect)
    rows_flat = rows.reshape(-1)
    # Exponents in float64, rounded once: in the working precision the polynomial's rounding
    # (~1e-7 of terms up to ~1e2) would dominate the error of the whole rasterizer.
    coeffs = st.coeffs.index_select(0, rows_flat).view(ta, lb, 6)
    t = _log_alpha(coeffs, st.neg_basis, tiles, st.work64.get("t64", (ta * lb, slots)))
    # A copy even in float64: alpha is made from t in place and kept for the backward pass, while
    # the float64 buffer is reused by the next block.
    t = t.to(dtype, copy=True).view(ta, lb, slots)
    maybe_clamped = bool(t.amax() > _CLAMP_FLAG_ABOVE)
    t.clamp_(-_T_SKIP - 1.0, -_T_CLAMP)  # log alpha, [Ta, L, S]
    # threshold (not masked_fill with a bool mask): several times faster on CPU.
    alpha = torch.nn.functional.threshold_(t.exp_(), st.keep_alpha_above, 0.0)
    if plan.slot_valid is not None:
        alpha.mul_(plan.slot_valid[tiles][:, None, :])
    log_t = torch.neg(alpha, out=st.work.get("log_t", alpha.shape)).log1p_()
    first = log_t[:, 0, :].clone()
    log_t[:, 0, :] += carry
    incl = torch.cumsum(log_t, 1)  # log T after each row; becomes the weights below
    log_t[:, 0, :] = first
    if float(carry.max()) > _LOG_HALF:  # else no sample of the block is above T = 0.5
        above = torch.gt(incl, _LOG_HALF, out=st.work.get("above", incl.shape, torch.bool))
        st.crossing.index_add_(0, tiles, above.sum(1, dtype=torch.int32))
    carry = incl[:, -1, :].clone()
    # Dropped rows (log T after them <= log 1e-4) get log T = -30 + 6.9 at most before the row,
    # so T < 1e-9 there, while live rows have T > 1e-4: the threshold after exp zeroes exactly
    # the dropped rows.
    torch.nn.functional.threshold_(incl, _LOG_T_MIN, -30.0)
    trans = torch.nn.functional.threshold_(incl.sub_(log_t).exp_(), _DROPPED_T, 0.0)
    w = trans.mul_(alpha)
    if st.before_cutoff is not None:
        front = _in_front(plan, st.gid_ext, tiles, rows, w)
        st.before_cutoff.index_add_(0, tiles, (alpha * front).sum(1))
    f_rows = feats.index_select(0, st.gid_ext.index_select(0, rows_flat)).view(ta, lb, d)
    st.out.index_add_(0, tiles, torch.bmm(f_rows.transpose(1, 2).contiguous(), w))
    return _Block(tiles, rows, f_rows, alpha, w, maybe_clamped), carry


class TileComposite(torch.autograd.Function):
    """Composite all tiles; returns (sample sums [T*S, D], crossing counts [T, S]) and, when the
    plan has ``cutoff_depths``, the summed alpha in front of each sample's cut-off [T*S].

    Inputs: ``coeffs`` [I, 6] (from :func:`quadratic_coefficients`, in the plan's intersection
    order), ``feats`` [G, D] (indexed by ``plan.gaussian_ids``) and the :class:`CompositePlan`.
    ``crossing`` counts, per sample, the rows after which ``T > 0.5`` still holds (the index of
    the median Gaussian in the tile's run when it is smaller than the run length).
    """

    @staticmethod
    def forward(ctx, coeffs, feats, plan: CompositePlan):
        device, dtype = feats.device, feats.dtype
        n_tiles, slots, n_isect, d = plan.num_tiles, plan.slots, coeffs.shape[0], feats.shape[1]
        # The coefficients come in float64 (their sum cancels). The basis is negated, so the
        # product is log alpha directly (no negation pass per block).
        sentinel = torch.zeros(1, 6, device=device, dtype=coeffs.dtype)
        sentinel[0, 0] = _SENTINEL_EXPONENT
        counts = plan.tile_offsets[1:] - plan.tile_offsets[:-1]
        st = _ForwardState(
            plan=plan,
            coeffs=torch.cat([coeffs.detach(), sentinel]),
            neg_basis=-plan.basis,
            feats=feats,
            gid_ext=torch.cat([plan.gaussian_ids, plan.gaussian_ids.new_zeros(1)]),
            counts=counts,
            ranks=torch.arange(max(1, int(counts.max())) if n_tiles else 1, device=device),
            # Sums kept as [T, D, S]: bmm(features^T, weights) with both operands contiguous
            # is 2-3x faster on CPU than bmm(weights^T, features); transposed once at the end.
            out=torch.zeros(n_tiles, d, slots, device=device, dtype=dtype),
            # int32 counts: a bool -> int64 sum casts the whole mask first (several times slower).
            crossing=torch.zeros(n_tiles, slots, device=device, dtype=torch.int32),
            before_cutoff=None if plan.cutoff_depths is None else torch.zeros(n_tiles, slots, device=device, dtype=dtype),
            work=_Workspace(device, dtype),
            work64=_Workspace(device, coeffs.dtype),
            keep_alpha_above=_below(ALPHA_MIN, dtype),
        )
        blocks = []
        # Tiles go in groups of similar list length (sorted by it), each group through all its
        # depth blocks before the next: a block of ~block_elems values keeps the temporaries in
        # cache (a pass over a DRAM-sized block costs several times more per value).
        nonempty = torch.nonzero(counts > 0).squeeze(1)
        nonempty = nonempty[torch.argsort(counts[nonempty], descending=True, stable=True)]
        block_elems = plan.block_elems or default_block_elems(device)
        group = max(1, block_elems // (_MIN_BLOCK_ROWS * slots))
        for g0 in range(0, nonempty.numel(), group):
            tiles = nonempty[g0 : g0 + group]
            carry = torch.zeros(tiles.numel(), slots, device=device, dtype=dtype)  # log T so far
            start = 0
            while tiles.numel() > 0:
                left = counts[tiles] - start
                lb = min(max(_MIN_BLOCK_ROWS, block_elems // (tiles.numel() * slots)), int(left.max()))
                blk, carry = _forward_block(st, tiles, start, carry, lb)
                blocks.append(blk)
                start += lb
                live = carry > _LOG_T_MIN
                if plan.slot_valid is not None:
                    live &= plan.slot_valid[tiles] > 0
                keep = (left > lb) & live.any(1)
                tiles, carry = tiles[keep], carry[keep]
        ctx.plan, ctx.blocks, ctx.n_isect = plan, blocks, n_isect
        ctx.save_for_backward(feats)
        crossing = st.crossing.long()
        ctx.mark_non_differentiable(crossing)
        out = st.out.transpose(1, 2).reshape(n_tiles * slots, d)
        if st.before_cutoff is not None:
            return out, crossing, st.before_cutoff.reshape(n_tiles * slots)
        return out, crossing

    @staticmethod
    def backward(ctx, grad_out, _grad_crossing, *grad_before_cutoff):
        (feats,) = ctx.saved_tensors
        plan: CompositePlan = ctx.plan
        n_isect, slots, d = ctx.n_isect, plan.slots, feats.shape[1]
        device, dtype = feats.device, feats.dtype
        g_pix_all = grad_out.reshape(plan.num_tiles, slots, d)
        g_pix_all_t = g_pix_all.transpose(1, 2).contiguous()  # [T, D, S], for a fast bmm
        g_coeffs = torch.zeros(n_isect + 1, 6, device=device, dtype=plan.basis.dtype)
        g_feats = torch.zeros_like(feats)
        gid_ext = torch.cat([plan.gaussian_ids, plan.gaussian_ids.new_zeros(1)])
        work = _Workspace(device, dtype)
        work64 = _Workspace(device, plan.basis.dtype)
        basis = plan.basis
        basis_t = basis.t() if basis.dim() == 2 else None
        max_rows = max((blk.rows.shape[1] for blk in ctx.blocks), default=1)
        ranks = torch.arange(max_rows, device=device)
        suffix = torch.zeros(plan.num_tiles, slots, device=device, dtype=torch.float64)  # sum g w behind
        g_before = None
        if grad_before_cutoff and grad_before_cutoff[0] is not None and plan.cutoff_depths is not None:
            g_before = grad_before_cutoff[0].reshape(plan.num_tiles, slots).to(dtype)
        for blk in reversed(ctx.blocks):
            tiles, rows, alpha, w = blk.tiles, blk.rows, blk.alpha, blk.weights
            ta, lb = rows.shape
            shape = (ta, lb, slots)
            g_pix = g_pix_all.index_select(0, tiles)  # [Ta, S, D]
            g_pix_t = g_pix_all_t.index_select(0, tiles)  # [Ta, D, S]
            gw = torch.bmm(blk.feats, g_pix_t, out=work.get("gw", shape))  # dL/dw
            if ctx.needs_input_grad[1]:
                gid = gid_ext.index_select(0, rows.reshape(-1))
                g_feats.index_add_(0, gid, torch.bmm(w, g_pix).reshape(-1, d))
            gw.mul_(w)  # g w per (row, sample)
            # S_k = carried + sum_{m > k} g_m w_m, summed from the back in float32 (no cancellation
            # against the block total): buf[j] = sum of rows >= L - j after the cumsum
            # (buf[0] = 0, buf[j] = gw[L - j]), then S_k = carried + buf[L - 1 - k]. Reversals use
            # index_select with out= (torch.flip is several times slower on CPU).
            rev = ranks[:lb].flip(0)
            buf = torch.index_select(gw, 1, torch.roll(rev, 1), out=work.get("buf", shape))
            buf[:, 0, :] = 0.0
            buf.cumsum_(1)
            behind = torch.index_select(buf, 1, rev, out=work.get("behind", shape))
            carried = suffix.index_select(0, tiles)
            # The block's total (rows >= 1 from the cumsum, row 0 added) joins the float64 carry.
            suffix.index_copy_(0, tiles, carried + buf[:, lb - 1, :].double() + gw[:, 0, :].double())
            behind.add_(carried.to(dtype)[:, None, :])
            # p = dL/d(exponent) = -alpha dL/dalpha = S alpha / (1 - alpha) - g w.
            one_minus = torch.mul(alpha, -1.0, out=work.get("one_minus", shape)).add_(1.0)
            p = behind.mul_(alpha).div_(one_minus).sub_(gw)
            if g_before is not None:  # line of sight: dL/dalpha += g on rows in front of the cut-off
                front = _in_front(plan, gid_ext, tiles, rows, w)
                p.sub_(alpha * front * g_before.index_select(0, tiles)[:, None, :])
            if blk.maybe_clamped:  # clamped alpha has no gradient
                p.masked_fill_(alpha >= _ALPHA_CLAMPED, 0.0)
            # Moments in float64: the chain back to means and conics cancels like the forward
            # (float32 moments fail the dense-reference gradient test).
            p64 = work64.get("p64", shape).copy_(p)
            if basis_t is not None:
                r = p64.view(-1, slots) @ basis_t
            else:
                r = torch.bmm(p64, basis.index_select(0, tiles).transpose(1, 2)).reshape(-1, 6)
            g_coeffs.index_copy_(0, rows.reshape(-1), r)  # each real row once; sentinel dropped
        return g_coeffs[:n_isect], g_feats, None
