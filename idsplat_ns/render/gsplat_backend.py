"""gsplat CUDA kernels behind :func:`idsplat_ns.render.rasterize_camera` (CUDA only).

Features, a ones channel (alpha) and one-hot instance channels are rendered together by
``gsplat.rasterization`` in "RGB+ED" mode (expected depth as the last channel). gsplat's fused
kernel has no median depth: this backend returns the expected depth in its place. Images differ
from the torch backend only where gsplat's tile-limited 3-sigma footprint cuts a Gaussian that
the torch path still sees (there alpha < 0.011 * opacity); see docs/rendering.md.
"""

from __future__ import annotations

import importlib.util
from typing import Optional

import torch
from torch import Tensor

from ..errors import IDSplatError
from .camera_render import CameraRender
from .rolling_shutter import shifted_world_means


def gsplat_available() -> bool:
    """Whether gsplat is installed (its CUDA kernels are only built, and imported, when used)."""
    return importlib.util.find_spec("gsplat") is not None


def rasterize_camera_gsplat(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    *,
    instance_ids: Optional[Tensor] = None,  # [N] int64
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    return_instance_alpha: bool = False,
    motion=None,  # Optional[CameraMotion]
):
    """Same outputs as the torch backend, computed by ``gsplat.rasterization`` on CUDA.

    With a rolling-shutter ``motion`` the means are moved to their exposure time per camera
    (:func:`~idsplat_ns.render.rolling_shutter.shifted_world_means`, the torch path's shift) and
    the cameras are rendered one by one, since gsplat takes one set of 3D means per call.
    """
    if not means.is_cuda:
        raise IDSplatError("rasterize_camera: backend='gsplat' needs CUDA tensors; use backend='torch' on CPU")
    if motion is not None:
        return _per_camera_shifted(
            means, quats, scales, opacities, features, viewmats, Ks, width, height, instance_ids=instance_ids,
            near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, return_instance_alpha=return_instance_alpha,
            motion=motion,
        )
    from gsplat import rasterization  # imported here: gsplat's CUDA build is only needed on GPUs


    n, d = features.shape
    columns = [features, torch.ones_like(features[:, :1])]
    inst_values = None
    if instance_ids is not None:
        inst_values, inverse = torch.unique(instance_ids, return_inverse=True)
        columns.append(torch.nn.functional.one_hot(inverse, inst_values.numel()).to(features.dtype))
    colors = torch.cat(columns, dim=1)
    render, alpha, meta = rasterization(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height,
        near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, render_mode="RGB+ED",
        packed=False, absgrad=False,
    )  # fmt: skip
    # RGB+ED: the last channel is the expected depth (already divided by alpha).
    depth = render[..., -1:]
    feats = render[..., :d]
    has = alpha > 0
    if instance_ids is None:
        inst_id = torch.where(has[..., 0], 0, -1).to(torch.int64)
        inst_alpha = None
    else:
        inst_alpha = render[..., d + 1 : -1]
        inst_id = torch.where(has[..., 0], inst_values[inst_alpha.detach().argmax(-1)], -1)
    return CameraRender(
        features=feats, alpha=alpha, depth=torch.where(has, depth, 0.0),
        median_depth=torch.where(has, depth, 0.0), instance_id=inst_id,
        means2d=meta["means2d"], radii=meta["radii"], depths=meta["depths"],
        instance_alpha=inst_alpha if return_instance_alpha else None,
        instance_values=inst_values if return_instance_alpha else None,
    )  # fmt: skip


def _per_camera_shifted(means, quats, scales, opacities, features, viewmats, Ks, width, height, *, motion, **kwargs):
    """Rolling shutter on gsplat: one call per camera with that camera's shifted means, stacked."""
    shifted = shifted_world_means(means, viewmats, Ks, motion, width, height)  # [C, N, 3]
    parts = [rasterize_camera_gsplat(shifted[c], quats, scales, opacities, features, viewmats[c : c + 1], Ks[c : c + 1],
                                     width, height, **kwargs) for c in range(viewmats.shape[0])]
    if kwargs.get("instance_ids") is not None and kwargs.get("return_instance_alpha"):
        # Every call sees the same instance IDs, so the channels line up.
        inst_alpha, inst_values = torch.cat([p.instance_alpha for p in parts]), parts[0].instance_values
    else:
        inst_alpha, inst_values = None, None
    cat = {k: torch.cat([getattr(p, k) for p in parts]) for k in
           ("features", "alpha", "depth", "median_depth", "instance_id", "means2d", "radii", "depths")}
    return CameraRender(**cat, instance_alpha=inst_alpha, instance_values=inst_values)
