"""The camera rasterizer: :func:`rasterize_camera` (its output: :class:`~idsplat_ns.render.camera_render.CameraRender`)."""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

from ..errors import IDSplatError
from .camera_render import CameraRender
from .compositor import choose_compositor
from .gsplat_backend import gsplat_available, rasterize_camera_gsplat
from .projection import Projection, project_gaussians
from .rolling_shutter import CameraMotion
from .tile_composite import CompositePlan, TileCoefficients, TileComposite, pixel_basis
from .tiles import intersect_tiles, tile_centres, tiles_to_image


def _check_inputs(means, quats, scales, opacities, features, viewmats, Ks, instance_ids) -> None:
    n = means.shape[0]
    expect = {
        "means": (means, (n, 3)),
        "quats": (quats, (n, 4)),
        "scales": (scales, (n, 3)),
        "opacities": (opacities, (n,)),
    }
    for name, (t, shape) in expect.items():
        if tuple(t.shape) != shape:
            raise IDSplatError(f"rasterize_camera: {name} has shape {tuple(t.shape)}, expected {shape}")
    if features.dim() != 2 or features.shape[0] != n or features.shape[1] < 1:
        raise IDSplatError(f"rasterize_camera: features has shape {tuple(features.shape)}, expected ({n}, D>=1)")
    c = viewmats.shape[0]
    if viewmats.shape != (c, 4, 4) or Ks.shape != (c, 3, 3):
        raise IDSplatError(
            f"rasterize_camera: viewmats {tuple(viewmats.shape)} / Ks {tuple(Ks.shape)} must be [C,4,4] / [C,3,3]"
        )
    if instance_ids is not None and tuple(instance_ids.shape) != (n,):
        raise IDSplatError(f"rasterize_camera: instance_ids has shape {tuple(instance_ids.shape)}, expected ({n},)")


def _check_motion(motion: CameraMotion, n: int, c: int) -> None:
    t = motion.timing
    shapes = {"timing.t0": (t.t0, (c,)), "timing.du": (t.du, (c,)), "timing.dv": (t.dv, (c,)),
              "linear_velocity": (motion.linear_velocity, (c, 3)), "angular_velocity": (motion.angular_velocity, (c, 3))}
    if motion.velocities is not None:
        shapes["velocities"] = (motion.velocities, (n, 3))
    for name, (x, shape) in shapes.items():
        if tuple(x.shape) != shape:
            raise IDSplatError(f"rasterize_camera: motion.{name} has shape {tuple(x.shape)}, expected {shape}")


CAMERA_BACKENDS = ("auto", "torch", "gsplat")


def rasterize_camera(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4] wxyz
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    viewmats: Tensor,  # [C, 4, 4] world-to-camera, OpenCV axes
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    *,
    instance_ids: Optional[Tensor] = None,  # [N] int64, 0 = static background
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    backend: str = "auto",
    eps2d: float = 0.3,
    tile_size: int = 8,
    return_instance_alpha: bool = False,
    motion: Optional[CameraMotion] = None,
    chunk_elems: Optional[int] = None,
    compositor: str = "auto",
) -> CameraRender:
    """Render C pinhole cameras: features, alpha, expected/median depth and instance IDs.

    Gaussians are projected with :func:`project_gaussians` (gsplat's EWA projection with
    ``eps2d`` low-pass), composited front to back per pixel with gsplat's rules (see
    :mod:`idsplat_ns.render.reference`). Differentiable w.r.t. means, quats, scales, opacities,
    features and viewmats. ``backend``: ``"torch"`` (tile rasterizer, any device), ``"gsplat"``
    (CUDA kernels) or ``"auto"`` (gsplat when the inputs are on CUDA and gsplat is installed).
    ``tile_size``, ``chunk_elems`` (the torch compositor's block size; None: the device's
    default) and ``compositor`` (``"compiled"``: numba loops on CPU tensors, ``"triton"``: Triton
    kernels on float32 CUDA tensors, ``"torch"``: tensor ops on any device, ``"auto"``: compiled
    on the CPU, Triton on CUDA) only trade speed against memory in the
    torch backend; they never change the image beyond float rounding. ``return_instance_alpha``
    adds the per-instance alpha maps (one channel per distinct ID in ``instance_ids``). ``motion``: rolling shutter, each Gaussian drawn where it is when its
    line is exposed (:mod:`idsplat_ns.render.rolling_shutter`); None or a global timing renders
    every Gaussian at the camera's time.
    """
    _check_inputs(means, quats, scales, opacities, features, viewmats, Ks, instance_ids)
    if motion is not None:
        _check_motion(motion, means.shape[0], viewmats.shape[0])
        if motion.is_global():
            motion = None  # exactly the global-shutter path
    if backend not in CAMERA_BACKENDS:
        raise IDSplatError(f"rasterize_camera: backend={backend!r}; use 'auto', 'torch' or 'gsplat'")
    if backend == "auto":
        backend = "gsplat" if means.is_cuda and gsplat_available() else "torch"
    if backend == "gsplat":
        return rasterize_camera_gsplat(
            means, quats, scales, opacities, features, viewmats, Ks, width, height,
            instance_ids=instance_ids, near_plane=near_plane, far_plane=far_plane,
            eps2d=eps2d, return_instance_alpha=return_instance_alpha, motion=motion,
        )  # fmt: skip
    proj = project_gaussians(
        means, quats, scales, viewmats, Ks, width, height,
        eps2d=eps2d, near_plane=near_plane, far_plane=far_plane, motion=motion,
    )  # fmt: skip
    return rasterize_projected(
        proj, opacities, features, width, height,
        instance_ids=instance_ids, tile_size=tile_size,
        return_instance_alpha=return_instance_alpha, chunk_elems=chunk_elems, compositor=compositor,
    )  # fmt: skip


def rasterize_projected(
    proj: Projection,
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, D]
    width: int,
    height: int,
    *,
    instance_ids: Optional[Tensor] = None,  # [N] int64
    tile_size: int = 8,
    return_instance_alpha: bool = False,
    chunk_elems: Optional[int] = None,
    compositor: str = "auto",
) -> CameraRender:
    """Torch tile rasterizer on already projected Gaussians (see :func:`rasterize_camera`).

    Per-instance maps are composited as extra one-hot feature channels, one per distinct ID
    among the Gaussians that touch the image, so their cost grows with the visible instances.
    """
    cams, n = proj.depths.shape
    d = features.shape[1]
    device, dtype = features.device, features.dtype
    isects = intersect_tiles(
        proj.means2d.detach(), proj.covars2d.detach(), proj.depths.detach(), proj.radii,
        opacities.detach(), width, height, tile_size,
    )  # fmt: skip
    gid = isects.gaussian_ids
    flat_depths = proj.depths.reshape(-1)
    columns = [features.repeat(cams, 1), flat_depths[:, None], torch.ones_like(flat_depths[:, None])]
    inst_values = None
    if instance_ids is not None:
        # Channels only for the IDs of Gaussians that touch the image.
        inst_values = torch.unique(instance_ids[torch.unique(gid % n)])
        k = inst_values.numel()
        slot = torch.searchsorted(inst_values, instance_ids).clamp_max(max(k - 1, 0))
        match = (inst_values[slot] == instance_ids) if k else torch.zeros_like(instance_ids, dtype=torch.bool)
        onehot = (slot[:, None] == torch.arange(k, device=device)[None, :]) & match[:, None]
        columns.append(onehot.to(dtype).repeat(cams, 1))
    feats = torch.cat(columns, dim=1)  # [C*N, D + 2 (+ K)]
    b = tile_size
    plan = CompositePlan(
        tile_offsets=isects.tile_offsets, gaussian_ids=gid,
        basis=pixel_basis(b, device, torch.float64), block_elems=chunk_elems,
    )  # fmt: skip
    kind = choose_compositor(compositor, features)
    if kind == "compiled":
        from .compiled_composite import CompiledGaussianComposite  # numba only when it runs

        # Each row's coefficients are made inside the compiled loop from its Gaussian's
        # (mean, conic, log opacity), in float64 like quadratic_coefficients.
        per_gaussian = torch.cat(
            [proj.means2d.reshape(-1, 2).double(), proj.conics.reshape(-1, 3).double(),
             opacities.double().clamp_min(1e-30).log().repeat(cams)[:, None]], dim=1,
        )  # fmt: skip  # [C*N, 6]
        all_tiles = torch.arange(isects.num_tiles, device=device)
        centres = torch.stack(tile_centres(all_tiles, isects.tiles_x, isects.tiles_y, b), 1)  # [T, 2]
        pix, crossing = CompiledGaussianComposite.apply(per_gaussian, feats, plan, centres)
    else:
        # Per intersection: the exponent's coefficients in the pixel offset from the tile centre.
        cx, cy = tile_centres(isects.tile_ids, isects.tiles_x, isects.tiles_y, b)
        # One gather of (mean, conic, opacity) per intersection: index_select's backward is a
        # single index_add, far cheaper on CPU than three advanced-indexing backward passes. The
        # float64 coefficients come from a Function whose gradient is one [I, 6] tensor in the
        # input dtype, so the gradients are accumulated per Gaussian in the input dtype.
        per_gaussian = torch.cat(
            [proj.means2d.reshape(-1, 2), proj.conics.reshape(-1, 3), opacities.repeat(cams)[:, None]], dim=1
        )  # [C*N, 6]
        coeffs = TileCoefficients.apply(per_gaussian.index_select(0, gid), cx, cy)
        if kind == "triton":
            from .triton_composite import TritonTileComposite  # Triton only when it runs

            pix, crossing = TritonTileComposite.apply(coeffs, feats, plan)
        else:
            pix, crossing = TileComposite.apply(coeffs, feats, plan)
    out = tiles_to_image(pix, isects, width, height)
    feats_img, depth_sum, alpha = out[..., :d], out[..., d : d + 1], out[..., d + 1 : d + 2]
    has = alpha > 0
    depth = torch.where(has, depth_sum / torch.where(has, alpha, torch.ones_like(alpha)), 0.0)

    # Median: the Gaussian at which T first drops to <= 0.5 is the crossing-th of its tile list.
    counts = (isects.tile_offsets[1:] - isects.tile_offsets[:-1])[:, None]
    found = crossing < counts  # [T, B*B]
    row = (isects.tile_offsets[:-1, None] + crossing).clamp_max(max(gid.numel() - 1, 0))
    med_depth = flat_depths[gid[row]] if gid.numel() else torch.zeros(row.shape, device=device)
    med = tiles_to_image(torch.where(found, med_depth, 0.0).reshape(-1, 1), isects, width, height)
    found_img = tiles_to_image(found.reshape(-1, 1), isects, width, height)
    median_depth = torch.where(found_img, med, depth)

    inst_alpha = None
    if instance_ids is None:
        inst_id = torch.where(has[..., 0], 0, -1).to(torch.int64)
    else:
        inst_alpha = out[..., d + 2 :]
        if inst_values.numel() == 0:
            inst_id = torch.full(has.shape[:-1], -1, dtype=torch.int64, device=device)
        else:
            inst_id = torch.where(has[..., 0], inst_values[inst_alpha.detach().argmax(-1)], -1)
    return CameraRender(
        features=feats_img, alpha=alpha, depth=depth, median_depth=median_depth,
        instance_id=inst_id, means2d=proj.means2d, radii=proj.radii, depths=proj.depths,
        instance_alpha=inst_alpha if return_instance_alpha else None,
        instance_values=inst_values if return_instance_alpha else None,
    )  # fmt: skip
