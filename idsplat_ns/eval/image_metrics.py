"""Image metrics: PSNR, SSIM, DPSNR (PSNR inside dynamic-object masks, per class) and the
colour-aligned PSNR that some papers report (after the affine colour map that best fits the render
to the image).

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


def colour_aligned(pred: Tensor, gt: Tensor, ridge: float = 1e-6) -> Tensor:  # pred, gt: [H, W, 3] -> [H, W, 3]
    """``pred`` through the affine colour map ``x -> x M + c`` (12 numbers) that fits it best to
    ``gt`` in least squares, clamped to [0, 1]: what a per-image colour correction fitted to the
    image being scored would give. The normal equations in float64 with a small ridge, so that a
    flat image (a rank-deficient fit) stays finite on every device."""
    x = pred.reshape(-1, pred.shape[-1]).to(torch.float64)
    X = torch.cat([x, torch.ones_like(x[:, :1])], dim=1)  # [N, 4]
    y = gt.reshape(-1, gt.shape[-1]).to(torch.float64)
    A = X.T @ X + ridge * torch.eye(X.shape[1], dtype=X.dtype, device=X.device)
    coefficients = torch.linalg.solve(A, X.T @ y)  # [4, 3]
    return (X @ coefficients).clamp(0.0, 1.0).reshape(pred.shape).to(pred.dtype)


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
