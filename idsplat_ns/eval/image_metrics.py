"""Image metrics: PSNR, SSIM and DPSNR (PSNR inside dynamic-object masks, per class).

SSIM is the standard Wang et al. formulation with an 11x11 Gaussian window (sigma 1.5) and
reflection padding, averaged over the whole image: the convention of torchmetrics, which
nerfstudio's evaluation uses, so the numbers compare. Written here so it runs anywhere torch
runs; it is also the training loss's structural term.
"""

from __future__ import annotations

from typing import Optional

import torch
import torch.nn.functional as F
from torch import Tensor


def _gaussian_window(size: int, sigma: float, channels: int, like: Tensor) -> Tensor:
    coords = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, size, size).contiguous()


def ssim_map(
    img1: Tensor,  # [B, C, H, W] in [0, 1]
    img2: Tensor,  # [B, C, H, W] in [0, 1]
    window_size: int = 11,
    sigma: float = 1.5,
) -> Tensor:  # [B, C, H, W]
    """Per-pixel SSIM with reflection padding."""
    c = img1.shape[1]
    win = _gaussian_window(window_size, sigma, c, img1)
    pad = (window_size - 1) // 2
    img1 = F.pad(img1, (pad, pad, pad, pad), mode="reflect")
    img2 = F.pad(img2, (pad, pad, pad, pad), mode="reflect")
    mu1 = F.conv2d(img1, win, groups=c)
    mu2 = F.conv2d(img2, win, groups=c)
    s11 = (F.conv2d(img1 * img1, win, groups=c) - mu1**2).clamp(min=0)
    s22 = (F.conv2d(img2 * img2, win, groups=c) - mu2**2).clamp(min=0)
    s12 = F.conv2d(img1 * img2, win, groups=c) - mu1 * mu2
    c1, c2 = 0.01**2, 0.03**2
    return ((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1**2 + mu2**2 + c1) * (s11 + s22 + c2))


def ssim(img1: Tensor, img2: Tensor) -> Tensor:
    """Mean SSIM of [B, C, H, W] images in [0, 1] (a scalar)."""
    return ssim_map(img1, img2).mean()


def psnr(pred: Tensor, gt: Tensor, mask: Optional[Tensor] = None) -> Tensor:
    """PSNR (dB) of images in [0, 1], over all pixels or over ``mask`` (broadcastable bool).

    pred, gt: [..., H, W, C]; mask: [..., H, W] or [..., H, W, 1].
    """
    err = (pred - gt) ** 2
    if mask is None:
        mse = err.mean()
    else:
        m = mask.to(err.dtype)
        if m.dim() == err.dim() - 1:
            m = m[..., None]
        m = m.expand_as(err)
        mse = (err * m).sum() / m.sum().clamp(min=1)
    return -10 * torch.log10(mse.clamp(min=1e-10))


def dynamic_psnrs(pred: Tensor, gt: Tensor, masks: dict[str, Tensor]) -> dict[str, float]:
    """DPSNR of each non-empty dynamic mask: ``dynamic_mask<suffix>`` [H, W] or [H, W, 1] bool gives
    ``dpsnr<suffix>`` (``dpsnr`` moving vehicles, ``dpsnr_pedestrian``, ``dpsnr_cyclist``); keys
    not starting with ``dynamic_mask`` are ignored. pred, gt: [H, W, C] in [0, 1]."""
    out = {}
    for key, mask in masks.items():
        if key.startswith("dynamic_mask") and bool(mask.any()):
            m = mask.to(pred.device)
            out["dpsnr" + key[len("dynamic_mask"):]] = float(psnr(pred, gt, m[..., 0] if m.dim() == 3 else m))
    return out
