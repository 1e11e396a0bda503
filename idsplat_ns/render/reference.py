"""Dense reference rasterizer: every Gaussian against every pixel, plain autograd.

This is the definition the fast tile rasterizer (:mod:`idsplat_ns.render.composite`) must equal.
Compositing rule (gsplat 1.4.0's kernel without its tile dependence):

* pixel centres at ``(x + 0.5, y + 0.5)``; ``sigma = 0.5 (a dx^2 + c dy^2) + b dx dy``;
* ``alpha = min(0.999, opacity * exp(-max(sigma, 0)))`` (sigma < 0 only arises from rounding;
  gsplat skips it, here it counts as 0); a Gaussian is skipped at a pixel when it is culled
  (``radius == 0``) or ``alpha < 1/255``;
* front to back in depth order, weight ``w = alpha * T`` with ``T`` the product of ``1 - alpha``
  of the Gaussians in front; the Gaussian that would bring ``T`` to ``<= 1e-4`` and all behind it
  are dropped (gsplat's early stop);
* median depth: depth of the first Gaussian after which ``T <= 0.5``; where the pixel's alpha
  stays below 0.5 it falls back to the expected depth (0 where nothing contributes).

Memory is ``O(C * H * W * N)``: only for tests and for the benchmark's speed-up ratio.
"""

from __future__ import annotations

from typing import Tuple

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0  # gsplat's per-pixel skip threshold
ALPHA_MAX = 0.999  # gsplat's clamp (keeps 1 - alpha away from 0)
TRANSMITTANCE_MIN = 1e-4  # gsplat's early-stop threshold


def pixel_alphas(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    active: Tensor,  # [N] bool, False for culled Gaussians
    px: Tensor,  # [P] pixel centre x
    py: Tensor,  # [P] pixel centre y
) -> Tensor:
    """Alpha of every Gaussian at every pixel with the skip rules applied: returns [P, N]."""
    dx = means2d[None, :, 0] - px[:, None]
    dy = means2d[None, :, 1] - py[:, None]
    sigma = 0.5 * (conics[None, :, 0] * dx * dx + conics[None, :, 2] * dy * dy) + (
        conics[None, :, 1] * dx * dy
    )
    alpha = torch.clamp_max(opacities[None, :] * torch.exp(-sigma.clamp_min(0.0)), ALPHA_MAX)
    keep = (alpha >= ALPHA_MIN) & active[None, :]
    return torch.where(keep, alpha, torch.zeros_like(alpha))


def composite_weights(alpha: Tensor) -> Tuple[Tensor, Tensor]:  # alpha: [P, K] depth-sorted
    """Front-to-back weights with gsplat's early stop.

    Returns (weights [P, K], transmittance before each Gaussian [P, K]).
    """
    one_minus = 1.0 - alpha
    t_incl = torch.cumprod(one_minus, dim=1)
    t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=1)
    keep = t_incl > TRANSMITTANCE_MIN
    weights = torch.where(keep, alpha * t_excl, torch.zeros_like(alpha))
    return weights, t_excl


def rasterize_dense(
    means2d: Tensor,  # [C, N, 2]
    conics: Tensor,  # [C, N, 3]
    depths: Tensor,  # [C, N]
    radii: Tensor,  # [C, N] int
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    width: int,
    height: int,
) -> Tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Dense rasterization of projected Gaussians.

    Returns features [C,H,W,D], alpha [C,H,W,1], depth-weighted sum [C,H,W,1] (not divided by
    alpha), median depth [C,H,W,1] and the per-pixel weights [C,H*W,N] (original Gaussian order)
    so that callers can derive per-instance maps.
    """
    cams = means2d.shape[0]
    ys, xs = torch.meshgrid(
        torch.arange(height, device=means2d.device, dtype=means2d.dtype) + 0.5,
        torch.arange(width, device=means2d.device, dtype=means2d.dtype) + 0.5,
        indexing="ij",
    )
    px, py = xs.reshape(-1), ys.reshape(-1)
    outs = []
    for c in range(cams):
        order = torch.argsort(depths[c].detach(), stable=True)
        alpha = pixel_alphas(
            means2d[c, order], conics[c, order], opacities[order], radii[c, order] > 0, px, py
        )
        weights, t_excl = composite_weights(alpha)
        feat = weights @ features[order]
        acc = weights.sum(dim=1, keepdim=True)
        depth_sum = weights @ depths[c, order][:, None]
        # Median: first Gaussian after which T <= 0.5, else the expected depth.
        t_incl = t_excl * (1.0 - alpha)
        crosses = (t_incl <= 0.5) & (weights > 0)
        k = alpha.shape[1]
        first = torch.where(crosses, torch.arange(k, device=alpha.device), k).amin(dim=1)
        has = acc[:, 0] > 0
        expected = torch.where(has, depth_sum[:, 0] / torch.where(has, acc[:, 0], 1.0), 0.0)
        med = torch.where(first < k, depths[c, order][first.clamp_max(k - 1)], expected)
        w_orig = torch.empty_like(weights)
        w_orig[:, order] = weights
        outs.append((feat, acc, depth_sum, med[:, None], w_orig))
    shape = (cams, height, width, -1)
    return (
        torch.stack([o[0] for o in outs]).reshape(shape),
        torch.stack([o[1] for o in outs]).reshape(shape),
        torch.stack([o[2] for o in outs]).reshape(shape),
        torch.stack([o[3] for o in outs]).reshape(shape),
        torch.stack([o[4] for o in outs]),
    )
