"""The relocation rule of 3DGS-as-MCMC (Kheradmand et al. 2024, Eq. 9) and opacity-weighted sampling.

When a Gaussian of opacity ``o`` and scale ``s`` is shared among ``n`` Gaussians (itself and
``n - 1`` copies at the same place), each of them gets

    o_new = 1 - (1 - o)^(1/n)
    s_new = o / D(n, o_new) * s,   D(n, x) = sum_{i=1}^{n} sum_{k=0}^{i-1} C(i-1, k) (-1)^k x^(k+1) / sqrt(k+1)

so that the rendered opacity profile of the group matches the original Gaussian's. The double sum
collapses (hockey-stick identity, sum_{i=k+1}^{n} C(i-1, k) = C(n, k+1)) to the single sum

    D(n, x) = sum_{j=1}^{n} (-1)^(j-1) C(n, j) x^j / sqrt(j),

which is evaluated here in float64 with log-binomials, for any ``n`` (gsplat's CUDA kernel caps
``n`` at 51 instead). It alternates, but its terms are bounded by ``(1 + x)^n`` and
``x <= -log(1 - o) / n``, so with ``o`` clamped below ``1 - 2^-23`` no term exceeds ``e^16.7`` and
float64 keeps the sum accurate.
"""

from __future__ import annotations

import torch
from torch import Tensor

# Largest float32 opacity strictly below 1: an opacity of exactly 1 has no finite logit and makes
# (1 - o)^(1/n) zero.
_MAX_OPACITY = 1.0 - 2.0**-24


def relocation_denominator(n: Tensor, x: Tensor) -> Tensor:
    """``D(n, x)`` of the module docstring, in float64.

    n: [M] int64 >= 1, group sizes; x: [M] new opacities in (0, 1); returns [M] float64.
    """
    n = n.to(torch.int64)
    x = x.to(torch.float64)
    # One flat entry per (group, j) with j = 1..n of that group: memory is sum(n) = number of
    # Gaussians involved, so large groups cost no padding.
    group = torch.repeat_interleave(torch.arange(len(n), device=n.device), n)
    starts = torch.cumsum(n, 0) - n
    j = (torch.arange(int(n.sum()), device=n.device) - starts[group] + 1).to(torch.float64)
    nn_ = n.to(torch.float64)[group]
    log_binom = torch.lgamma(nn_ + 1) - torch.lgamma(j + 1) - torch.lgamma(nn_ - j + 1)
    magnitude = torch.exp(log_binom + j * torch.log(x[group]) - 0.5 * torch.log(j))
    sign = 1.0 - 2.0 * torch.remainder(j - 1, 2)  # (-1)^(j-1)
    return torch.zeros(len(n), dtype=torch.float64, device=n.device).index_add_(0, group, sign * magnitude)


def relocation_update(
    opacities: Tensor,  # [M] activated opacities of the sources, in (0, 1)
    scales: Tensor,  # [M, 3] activated scales of the sources
    counts: Tensor,  # [M] int, how many Gaussians share each source (source included), >= 1
) -> tuple[Tensor, Tensor]:
    """New opacity and scale for each member of a group of ``counts`` Gaussians replacing one.

    Returns ``(new_opacities [M], new_scales [M, 3])`` in the dtype of the inputs. A count of 1
    returns the inputs unchanged (up to rounding).
    """
    o = opacities.to(torch.float64).clamp(min=1e-12, max=_MAX_OPACITY)
    n = counts.to(torch.int64)
    # 1 - (1 - o)^(1/n), written with log1p/expm1 to keep precision when o or 1/n is small.
    x = -torch.expm1(torch.log1p(-o) / n.to(torch.float64))
    coefficient = o / relocation_denominator(n, x)
    new_scales = scales.to(torch.float64) * coefficient[:, None]
    return x.to(opacities.dtype), new_scales.to(scales.dtype)


def sample_proportional(weights: Tensor, num: int, generator: torch.Generator | None = None) -> Tensor:
    """``num`` indices drawn with replacement with probability proportional to ``weights`` [N] (>= 0).

    Inverse-CDF sampling in float64: no category limit (``torch.multinomial`` stops at 2^24) and
    the same draws on any device for a given generator state. Zero weights are never drawn.
    Returns [num] int64 on the weights' device.
    """
    cdf = torch.cumsum(weights.detach().to(torch.float64).clamp_min(0.0), 0)
    if len(cdf) == 0 or not float(cdf[-1]) > 0.0:
        raise ValueError("sample_proportional needs at least one positive weight")
    u = torch.rand(num, generator=generator, dtype=torch.float64, device=weights.device) * cdf[-1]
    # right=True: u in [cdf[i-1], cdf[i]) maps to i, so an empty interval (zero weight) never wins.
    # The clamp (to the last positive weight) only catches u rounding up to the total.
    last_positive = torch.searchsorted(cdf, cdf[-1:], right=False)
    return torch.minimum(torch.searchsorted(cdf, u, right=True), last_positive)
