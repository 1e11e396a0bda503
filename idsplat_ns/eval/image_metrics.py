"""Image metrics: PSNR, SSIM and DPSNR (PSNR inside dynamic-object masks, per class).

SSIM is torchmetrics' (Wang et al., 11x11 Gaussian window, sigma 1.5, reflection padding, averaged
over the whole image), the implementation nerfstudio's evaluation uses, so the numbers compare; it
is also the training loss's structural term (it is differentiable).
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor
from torchmetrics.functional.image import structural_similarity_index_measure


def ssim_map(
    img1: Tensor,  # [B, C, H, W] in [0, 1]
    img2: Tensor,  # [B, C, H, W] in [0, 1]
    window_size: int = 11,
    sigma: float = 1.5,
) -> Tensor:  # [B, C, H, W]
    """Per-pixel SSIM with reflection padding."""
    _, full = structural_similarity_index_measure(
        img1, img2, gaussian_kernel=True, sigma=sigma, kernel_size=window_size, data_range=1.0,
        reduction="none", return_full_image=True,
    )
    return full


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
