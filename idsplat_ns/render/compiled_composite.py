"""Tile compositing on the CPU as compiled loops (numba): the contract of
:class:`~idsplat_ns.render.tile_composite.TileComposite`, gsplat's kernel structure.

Why compiled: torch's CPU ops composite whole ``[rows, samples]`` blocks through memory, each
pass a kernel of its own; a loop per tile keeps a row's work in registers and L1, stops at the
tile's early stop, and keeps nothing for the backward pass but each sample's final transmittance
and stop row.

Tiles are dealt to ``torch.get_num_threads()`` Python threads that run the compiled loops with
the GIL released (longest lists first, round-robin, so the threads take about as long). Inside a
tile, rows go front to back and the tile's samples in lockstep, as the threads of a CUDA block
do, so every inner loop runs over the samples without branches (selects) and is vectorised:

* exponent ``e = coeffs[row] . basis[:, s]`` in float64 (its terms cancel; see
  :mod:`idsplat_ns.render.tile_composite`), rounded once to the working dtype;
* ``alpha = exp(-clamp(e, -log 0.999, -log(1/255) + 1))``, zero below 1/255 and on padding or
  stopped samples (``exp`` is a polynomial, :func:`_exp_neg`: libm's is not vectorised);
* ``T`` the product of ``1 - alpha``; the row that would bring it to ``<= 1e-4`` and all behind
  it are dropped; ``crossing`` counts the rows after which ``T > 0.5``;
* with a cut-off (lidar line of sight), the alphas of composited rows in front of the sample's
  cut-off are summed.

The backward pass runs each tile's rows back to front from its last composited row, recovering
``T`` before each row by division by the same ``1 - alpha`` (gsplat's backward), ``_BATCH`` rows
at a time before their gradients are taken, with
``S = sum_{m > k} g_m w_m`` (float64): ``dL/de_k = S alpha_k / (1 - alpha_k) - g_k w_k`` (zero at
the 0.999 clamp), minus ``alpha_k g_cutoff`` for rows in front of the cut-off; the coefficient
gradient is its moments against the basis, in float64. A row belongs to one tile, so its
coefficient gradient has one writer; feature gradients are summed per thread, then added.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Optional

import numpy as np
import torch
from numba import njit
from torch import Tensor

from .reference import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN

_E_SKIP = -math.log(ALPHA_MIN)  # exponents above this give alpha < 1/255
_E_CLAMP = -math.log(ALPHA_MAX)  # exponents at or below this give the 0.999 clamp
_EXP_SQUARINGS = 4  # exp(-e) = exp(-e / 16)^16
# Constants in the working dtype (numba promotes float32 with a Python float to float64, which
# halves the vector width): the kernels read them from this array into locals.
_CONSTANTS = np.array(
    [_E_CLAMP, _E_SKIP + 1.0, ALPHA_MIN, TRANSMITTANCE_MIN, 0.5, 1.0, 0.0, 2.0**-_EXP_SQUARINGS]
    + [1.0 / math.factorial(k) for k in range(2, 10)]
)
# Flags that let the compiler vectorise and reassociate sums; none that assumes finite values.
_FAST = {"reassoc", "contract", "nsz", "arcp"}
_BATCH = 32  # rows recovered (backward) before their gradients are taken, one after another
# Inner loops run over a tile's samples with selects written as arithmetic (``one * (x > y)``
# and ``k * a + (one - k) * b``): numba compiles a conditional expression to a branch, which the
# loop vectoriser gives up on, and a blend of exact 0/1 weights is exact.
_JIT = dict(nogil=True, cache=True, fastmath=_FAST, error_model="numpy")


@njit(inline="always", fastmath=_FAST)
def _exp_neg(e, scale, one, c2, c3, c4, c5, c6, c7, c8, c9):
    """``exp(-e)`` for ``0 <= e <= 7``: degree-9 Taylor polynomial of ``exp(-e / 16)``, squared
    four times: 1e-9 relative in float64, 2e-6 in float32 (tested), with no branches or integers
    (libm's exp is not vectorised)."""
    x = -e * scale
    p = one + x * (one + x * (c2 + x * (c3 + x * (c4 + x * (c5 + x * (c6 + x * (c7 + x * (c8 + x * c9))))))))
    p = p * p
    p = p * p
    p = p * p
    return p * p


@njit(inline="always")
def _alpha_constants(consts):
    """What :func:`_alpha` needs, from the kernels' ``consts`` (see :data:`_CONSTANTS`)."""
    return (consts[0], consts[1], consts[2], consts[7], consts[5], consts[8], consts[9], consts[10],
            consts[11], consts[12], consts[13], consts[14], consts[15])  # fmt: skip


@njit(inline="always", fastmath=_FAST)
def _alpha(e, ac):
    """Alpha of exponent ``e``: ``exp(-e)`` clamped at 0.999, zero below 1/255 (``ac`` from
    :func:`_alpha_constants`)."""
    e_clamp, e_max, alpha_min, scale, one = ac[0], ac[1], ac[2], ac[3], ac[4]
    al = _exp_neg(min(max(e, e_clamp), e_max), scale, one, ac[5], ac[6], ac[7], ac[8], ac[9], ac[10], ac[11], ac[12])
    return al * (one * (al >= alpha_min))


@njit(inline="always")
def _row_coefficients(p, cx, cy):
    """:func:`~idsplat_ns.render.tile_composite.quadratic_coefficients` of one row: ``p`` =
    (mean x, mean y, a, b, c, log opacity) of its Gaussian, ``(cx, cy)`` its tile's centre."""
    dx, dy, a, b, c = p[0] - cx, p[1] - cy, p[2], p[3], p[4]
    adx, cdy = a * dx, c * dy
    k0 = 0.5 * (adx * dx + cdy * dy) + b * dx * dy - p[5]
    return k0, -(adx + b * dy), -(cdy + b * dx), 0.5 * a, b, 0.5 * c


@njit(inline="always")
def _add_params_gradient(g, p, cx, cy, g0, g1, g2, g3, g4, g5):
    """Add to ``g`` [6] the gradient of :func:`_row_coefficients`'s ``p`` from the coefficients'
    gradient ``(g0, ..., g5)`` (the chain of :class:`~idsplat_ns.render.tile_composite.TileCoefficients`)."""
    dx, dy, a, b, c = p[0] - cx, p[1] - cy, p[2], p[3], p[4]
    u, v = g0 * dx - g1, g0 * dy - g2  # d/d(dx), d/d(dy) share these
    g[0] += a * u + b * v
    g[1] += b * u + c * v
    g[2] += 0.5 * (g0 * dx - 2.0 * g1) * dx + 0.5 * g3
    g[3] += g0 * dx * dy - g1 * dy - g2 * dx + g4
    g[4] += 0.5 * (g0 * dy - 2.0 * g2) * dy + 0.5 * g5
    g[5] -= g0


@njit(inline="always")
def _tile_basis(basis, centres, t, from_coeffs):
    """Tile ``t``'s basis [6, S] and its centre (the origin of the parameters' offsets)."""
    b = basis[0] if basis.shape[0] == 1 else basis[t]
    cx, cy = (0.0, 0.0) if from_coeffs else (centres[t, 0], centres[t, 1])
    return b, cx, cy


@njit(inline="always", fastmath=_FAST)
def _row_exponents(e, r, b, coeffs, params, gid, cx, cy, from_coeffs):
    """Write the exponent of row ``r`` at every sample into ``e`` [S]: the polynomial in float64
    (its terms cancel), rounded once into ``e``'s dtype."""
    if from_coeffs:
        k0, k1, k2, k3, k4, k5 = coeffs[r, 0], coeffs[r, 1], coeffs[r, 2], coeffs[r, 3], coeffs[r, 4], coeffs[r, 5]
    else:
        k0, k1, k2, k3, k4, k5 = _row_coefficients(params[gid[r]], cx, cy)
    b1, b2, b3, b4, b5 = b[1], b[2], b[3], b[4], b[5]
    for s in range(e.shape[0]):
        e[s] = k0 + k1 * b1[s] + k2 * b2[s] + k3 * b3[s] + k4 * b4[s] + k5 * b5[s]


@njit(**_JIT)
def _forward(coeffs, params, centres, basis, feats, gid, offsets, order, valid, cutoff, gdepth, consts,
             out, crossing, before, stop, t_final):  # fmt: skip
    """Composite the tiles in ``order``, the rows' coefficients read from ``coeffs`` [I, 6] or,
    when it is empty, made from ``params`` [G, 6] and ``centres`` [T, 2] (:func:`_row_coefficients`);
    writes ``out`` [T, D, S], ``crossing`` [T, S], ``before`` [T, S] (when ``cutoff`` is given),
    ``stop`` [T, S] (first dropped row relative to the tile's start, or its row count) and
    ``t_final`` [T, S] (T after the composited rows)."""
    ac, t_min, half, one, zero = _alpha_constants(consts), consts[3], consts[4], consts[5], consts[6]
    slots, d, from_coeffs = basis.shape[2], feats.shape[1], coeffs.shape[0] > 0
    has_valid, has_cutoff = valid.shape[0] > 0, cutoff.shape[0] > 0
    for i in range(order.shape[0]):
        t = order[i]
        b, cx, cy = _tile_basis(basis, centres, t, from_coeffs)
        start, end = offsets[t], offsets[t + 1]
        trans = np.empty(slots, feats.dtype)
        live = np.empty(slots, feats.dtype)
        e = np.empty(slots, feats.dtype)
        cross = np.zeros(slots, feats.dtype)  # exact counts (rows per tile < 2^24)
        first_drop = np.empty(slots, feats.dtype)
        w = np.empty(slots, feats.dtype)
        w_kept = np.empty(slots, feats.dtype)
        pending = -1  # feature row of a composited row not yet added to the sums
        a = np.empty(slots, feats.dtype)
        o = out[t]
        bf = before[t] if has_cutoff else before[0:0].reshape(-1)
        ct = cutoff[t] if has_cutoff else bf
        n_live = zero
        for s in range(slots):
            trans[s] = one
            live[s] = valid[t, s] if has_valid else one
            n_live += one * (live[s] > zero)
            first_drop[s] = end - start
        for r in range(start, end):
            if n_live == zero:
                break
            _row_exponents(e, r, b, coeffs, params, gid, cx, cy, from_coeffs)
            rank = one * (r - start)
            w_sum = zero
            for s in range(slots):
                al = _alpha(e[s], ac) * live[s]
                tr = trans[s]
                t_next = tr * (one - al)
                k = one * (t_next > t_min)  # 0 on the row that would drop T to <= 1e-4
                ws = k * al * tr
                cross[s] += k * (one * (t_next > half)) + (one - k) * (one * (tr > half))
                trans[s] = k * t_next + (one - k) * tr
                first_drop[s] = k * first_drop[s] + (one - k) * rank
                live[s] = k * live[s]
                n_live -= one - k
                a[s] = k * al
                w[s] = ws
                w_sum += ws
            if w_sum == zero:
                continue
            g = gid[r]
            if pending < 0:  # keep the row; it is added with the next one
                pending = g
                for s in range(slots):
                    w_kept[s] = w[s]
            else:  # two rows per pass over the sums: half the loads and stores of ``o``
                for j in range(d):
                    f0, f1 = feats[pending, j], feats[g, j]
                    oj = o[j]
                    for s in range(slots):
                        oj[s] += w_kept[s] * f0 + w[s] * f1
                pending = -1
            if has_cutoff:
                dg = gdepth[g]
                for s in range(slots):
                    bf[s] += a[s] * (one * (dg < ct[s])) * (one * (w[s] > zero))
        if pending >= 0:
            for j in range(d):
                f0 = feats[pending, j]
                oj = o[j]
                for s in range(slots):
                    oj[s] += w_kept[s] * f0
        for s in range(slots):
            crossing[t, s] = np.int32(cross[s])
            stop[t, s] = first_drop[s]
            t_final[t, s] = trans[s]


@njit(fastmath=_FAST, error_model="numpy", cache=True)
def _rows_backward(n, go, gb, ct, b, cx, cy, rows, g_rows, w_rows, a_rows, m_rows, behind,
                   feats, gdepth, params, has_cutoff, g_coeffs, g_params, g_feats, one, zero):  # fmt: skip
    """Gradients of a batch of ``n`` rows of one tile, collected back to front: ``go`` [D, S]
    the tile's output gradient, ``behind`` [S] (float64) the sum of ``g w`` behind the batch,
    updated. Rows ``rows`` [n] get their coefficient gradient (``g_coeffs``) or add their
    parameters' (``g_params``, when ``params`` is given); their features add to ``g_feats``."""
    from_coeffs = params.shape[0] == 0
    gw = np.empty(go.shape[1], go.dtype)
    for q in range(n):
        g = g_rows[q]
        w, a, m = w_rows[q], a_rows[q], m_rows[q]
        gfe = g_feats[g]
        for s in range(w.shape[0]):
            gw[s] = zero
        for j in range(go.shape[0]):  # dL/dw and dL/dfeature
            f, goj = feats[g, j], go[j]
            acc = zero
            for s in range(w.shape[0]):
                gw[s] += f * goj[s]
                acc += w[s] * goj[s]
            gfe[j] += acc
        dg = gdepth[g] if has_cutoff else zero
        q0 = q1 = q2 = q3 = q4 = q5 = 0.0
        for s in range(w.shape[0]):
            gws = gw[s] * w[s]
            ps = behind[s] * (a[s] / (one - a[s])) - gws
            if has_cutoff:  # line of sight: dL/dalpha += g on rows in front of the cut-off
                ps -= a[s] * gb[s] * (one * (dg < ct[s])) * (one * (w[s] > zero))
            ps = ps * m[s]
            behind[s] += gws
            q0 += ps
            q1 += ps * b[1, s]
            q2 += ps * b[2, s]
            q3 += ps * b[3, s]
            q4 += ps * b[4, s]
            q5 += ps * b[5, s]
        if from_coeffs:
            r = rows[q]
            g_coeffs[r, 0], g_coeffs[r, 1], g_coeffs[r, 2] = q0, q1, q2
            g_coeffs[r, 3], g_coeffs[r, 4], g_coeffs[r, 5] = q3, q4, q5
        else:
            _add_params_gradient(g_params[g], params[g], cx, cy, q0, q1, q2, q3, q4, q5)


@njit(**_JIT)
def _backward(coeffs, params, centres, basis, feats, gid, offsets, order, valid, cutoff, gdepth, consts,
              stop, t_final, g_out, g_before, g_coeffs, g_params, g_feats):  # fmt: skip
    """Gradients of :func:`_forward`'s outputs for the tiles in ``order``: ``g_out`` [T, D, S]
    and ``g_before`` [T, S] (empty: none) give ``g_coeffs`` [I, 6] (coefficient mode) or add to
    ``g_params`` [G, 6] (parameter mode), and add to ``g_feats`` [G, D] (one buffer per thread,
    summed by the caller). Rows are recovered back to front one by one and their gradients taken
    ``_BATCH`` rows at a time (:func:`_rows_backward`)."""
    ac, e_clamp, one, zero = _alpha_constants(consts), consts[0], consts[5], consts[6]
    slots, from_coeffs = basis.shape[2], coeffs.shape[0] > 0
    has_valid, has_cutoff = valid.shape[0] > 0, g_before.shape[0] > 0
    for i in range(order.shape[0]):
        t = order[i]
        b, cx, cy = _tile_basis(basis, centres, t, from_coeffs)
        start = offsets[t]
        trans = np.empty(slots, feats.dtype)
        live = np.empty(slots, feats.dtype)
        stop_t = np.empty(slots, feats.dtype)
        e = np.empty(slots, feats.dtype)
        w_rows = np.empty((_BATCH, slots), feats.dtype)
        a_rows = np.empty((_BATCH, slots), feats.dtype)
        m_rows = np.empty((_BATCH, slots), feats.dtype)
        g_rows = np.empty(_BATCH, np.int64)
        rows = np.empty(_BATCH, np.int64)
        behind = np.zeros(slots)  # float64: sum of g w of the rows behind
        go = g_out[t]
        gb = g_before[t] if has_cutoff else trans[0:0]
        ct = cutoff[t] if has_cutoff else gb
        last = 0.0
        for s in range(slots):
            trans[s] = t_final[t, s]
            live[s] = valid[t, s] if has_valid else one
            stop_t[s] = stop[t, s]
            last = max(last, stop[t, s])
        n = 0
        for r in range(start + np.int64(last) - 1, start - 1, -1):
            _row_exponents(e, r, b, coeffs, params, gid, cx, cy, from_coeffs)
            rank = one * (r - start)
            w, a, m = w_rows[n], a_rows[n], m_rows[n]
            w_sum = zero
            for s in range(slots):
                al = _alpha(e[s], ac) * live[s] * (one * (rank < stop_t[s]))
                t_before = trans[s] / (one - al)
                trans[s] = t_before
                a[s] = al
                # No gradient where alpha is zero or at the 0.999 clamp.
                m[s] = (one * (e[s] > e_clamp)) * (one * (al > zero))
                ws = al * t_before
                w[s] = ws
                w_sum += ws
            if w_sum == zero:
                continue
            g_rows[n], rows[n] = gid[r], r
            n += 1
            if n == _BATCH:
                _rows_backward(n, go, gb, ct, b, cx, cy, rows, g_rows, w_rows, a_rows, m_rows,
                               behind, feats, gdepth, params, has_cutoff, g_coeffs, g_params, g_feats, one, zero)  # fmt: skip
                n = 0
        if n > 0:
            _rows_backward(n, go, gb, ct, b, cx, cy, rows, g_rows, w_rows, a_rows, m_rows,
                           behind, feats, gdepth, params, has_cutoff, g_coeffs, g_params, g_feats, one, zero)  # fmt: skip


# Threads are Python threads running the kernels with the GIL released, not numba's parallel
# loops: numba's OpenMP pool is a second OpenMP runtime beside torch's, and with both spinning,
# two 1-thread trainings on 2 cores ran their camera steps 4x slower than one alone.
_POOL: Optional[ThreadPoolExecutor] = None
_POOL_WORKERS = 0
_POOL_LOCK = threading.Lock()


def _threads() -> int:
    return max(1, torch.get_num_threads())


def _run_split(kernel, order: np.ndarray, threads: int, per_part) -> None:
    """Run ``kernel(order=part, **per_part(k))`` on ``threads`` parts of ``order`` (dealt round-robin
    from the longest list down, so that the parts take about as long), the first part in this
    thread and the others in a shared pool of idle (blocked, not spinning) threads."""
    global _POOL, _POOL_WORKERS
    parts = [order[k::threads] for k in range(threads)]
    if threads == 1:
        kernel(order=parts[0], **per_part(0))
        return
    with _POOL_LOCK:
        # A larger pool for more threads; the old one is not shut down (a call may still be
        # submitting to it) and its idle workers exit once it is collected.
        if _POOL_WORKERS < threads - 1:
            _POOL = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="idsplat-composite")
            _POOL_WORKERS = threads - 1
        pool = _POOL
    futures = [pool.submit(kernel, order=parts[k], **per_part(k)) for k in range(1, threads)]
    kernel(order=parts[0], **per_part(0))
    for f in futures:
        f.result()


def _filled(shape: tuple, dtype, value: float = 0.0) -> np.ndarray:
    """An array the threaded kernels write into, its pages touched here, in one thread: fresh
    pages first written from two threads at once (page faults) made the camera's backward kernel
    on 2 threads no faster than on 1 (docs/reports/2026-11-27-cpu-rendering-speed.md)."""
    out = np.empty(shape, dtype)
    out.fill(value)
    return out


def _array(x: Tensor, dtype) -> np.ndarray:
    return np.ascontiguousarray(x.detach().to(dtype).numpy())


def _composite_forward(ctx, coeffs: np.ndarray, params: np.ndarray, centres: np.ndarray, feats: Tensor, plan):
    """Run :func:`_forward` and keep on ``ctx`` what :func:`_composite_backward` needs."""
    threads = _threads()
    dtype = feats.dtype
    n_tiles, slots, d = plan.num_tiles, plan.slots, feats.shape[1]
    offsets = plan.tile_offsets.numpy()
    counts = np.diff(offsets)
    nonempty = np.flatnonzero(counts > 0)
    order = nonempty[np.argsort(-counts[nonempty], kind="stable")]  # longest lists first
    np_dtype = torch.empty(0, dtype=dtype).numpy().dtype
    basis = plan.basis if plan.basis.dim() == 3 else plan.basis[None]
    has_cutoff = plan.cutoff_depths is not None
    arrays = dict(
        coeffs=coeffs, params=params, centres=centres, basis=_array(basis, torch.float64),
        feats=_array(feats, dtype), gid=_array(plan.gaussian_ids, torch.int64), offsets=offsets,
        valid=np.zeros((0, slots), np_dtype) if plan.slot_valid is None else _array(plan.slot_valid, dtype),
        cutoff=_array(plan.cutoff_depths, dtype) if has_cutoff else np.zeros((0, slots), np_dtype),
        gdepth=_array(plan.gaussian_depths, dtype) if has_cutoff else np.zeros(0, np_dtype),
        consts=_CONSTANTS.astype(np_dtype),
    )  # fmt: skip
    out = _filled((n_tiles, d, slots), np_dtype)
    crossing = _filled((n_tiles, slots), np.int32)
    before = _filled((n_tiles if has_cutoff else 0, slots), np_dtype)
    stop = _filled((n_tiles, slots), np.int64)  # rows relative to the tile's start
    t_final = _filled((n_tiles, slots), np_dtype, 1.0)
    outputs = dict(out=out, crossing=crossing, before=before, stop=stop, t_final=t_final)
    _run_split(_forward, order, threads, lambda k: {**arrays, **outputs})  # tiles are disjoint: shared outputs
    ctx.arrays, ctx.order, ctx.stop, ctx.t_final = arrays, order, stop, t_final
    ctx.threads, ctx.has_cutoff = threads, has_cutoff
    crossing_t = torch.from_numpy(crossing).long()
    ctx.mark_non_differentiable(crossing_t)
    out_t = torch.from_numpy(out).transpose(1, 2).reshape(n_tiles * slots, d)
    if has_cutoff:
        return out_t, crossing_t, torch.from_numpy(before).reshape(-1)
    return out_t, crossing_t


def _composite_backward(ctx, grad_out: Tensor, grad_before_cutoff: tuple):
    """Run :func:`_backward`: returns the gradients of (coeffs [I, 6], params [G, 6]) as arrays
    (the one not in use empty) and of the features as a tensor."""
    arrays = ctx.arrays
    n_tiles, slots = ctx.stop.shape
    feats, threads = arrays["feats"], ctx.threads
    g_out = _array(grad_out.reshape(n_tiles, slots, -1).transpose(1, 2), grad_out.dtype)  # [T, D, S]
    g_before = np.zeros((0, slots), feats.dtype)
    if ctx.has_cutoff and grad_before_cutoff and grad_before_cutoff[0] is not None:
        g_before = _array(grad_before_cutoff[0].reshape(n_tiles, slots), grad_out.dtype)
    g_coeffs = _filled(arrays["coeffs"].shape, arrays["coeffs"].dtype)
    g_params = _filled((threads,) + arrays["params"].shape, np.float64)  # [threads, 0, 6] in coefficient mode
    g_feats = _filled((threads,) + feats.shape, feats.dtype)
    shared = dict(arrays, stop=ctx.stop, t_final=ctx.t_final, g_out=g_out, g_before=g_before, g_coeffs=g_coeffs)
    # A row belongs to one tile (its coefficient gradient has one writer); a Gaussian's parameter
    # and feature gradients gather from many tiles, so each thread has buffers of its own.
    _run_split(_backward, ctx.order, threads, lambda k: dict(shared, g_params=g_params[k], g_feats=g_feats[k]))
    return g_coeffs, g_params.sum(0), torch.from_numpy(g_feats.sum(0))


def _no_params(dtype=np.float64) -> np.ndarray:
    return np.zeros((0, 6), dtype)


class CompiledTileComposite(torch.autograd.Function):
    """:class:`~idsplat_ns.render.tile_composite.TileComposite` computed by compiled loops on
    CPU tensors: the same inputs (``coeffs`` [I, 6], ``feats`` [G, D], the plan), outputs and
    gradients (to float rounding)."""

    @staticmethod
    def forward(ctx, coeffs, feats, plan):
        ctx.coeffs_dtype = coeffs.dtype
        return _composite_forward(ctx, _array(coeffs, torch.float64), _no_params(), _no_params()[:, :2], feats, plan)

    @staticmethod
    def backward(ctx, grad_out, _grad_crossing, *grad_before_cutoff):
        g_coeffs, _, g_feats = _composite_backward(ctx, grad_out, grad_before_cutoff)
        return torch.from_numpy(g_coeffs).to(ctx.coeffs_dtype), g_feats, None


class CompiledGaussianComposite(torch.autograd.Function):
    """The compiled compositor with each row's coefficients made inside the loop from its
    Gaussian (:func:`~idsplat_ns.render.tile_composite.quadratic_coefficients`), so no
    ``[I, 6]`` tensor is gathered and no coefficient chain runs through autograd.

    Inputs: ``params`` [G, 6] (mean x, mean y, conic a, b, c, log opacity) per feature row,
    ``feats`` [G, D], the plan and ``centres`` [T, 2] (float64) the tiles' centres, from which
    the basis offsets are measured. Outputs as :class:`CompiledTileComposite`; gradients for
    ``params`` (float64 sums, returned in its dtype) and ``feats``.
    """

    @staticmethod
    def forward(ctx, params, feats, plan, centres):
        ctx.params_dtype = params.dtype
        return _composite_forward(
            ctx, _no_params(), _array(params, torch.float64), _array(centres, torch.float64), feats, plan
        )

    @staticmethod
    def backward(ctx, grad_out, _grad_crossing, *grad_before_cutoff):
        _, g_params, g_feats = _composite_backward(ctx, grad_out, grad_before_cutoff)
        return torch.from_numpy(g_params).to(ctx.params_dtype), g_feats, None, None
