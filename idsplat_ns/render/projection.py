"""EWA projection of 3D Gaussians to pinhole cameras, with gsplat 1.4.0's conventions.

The maths follows gsplat's ``fully_fused_projection`` (pinhole model): camera-space mean
``t = R x + T``; Jacobian of the perspective map evaluated at ``t`` with ``x/z`` and ``y/z``
clamped to 1.3x the field of view (so that off-screen Gaussians do not blow up); 2D covariance
``J R Sigma R^T J^T`` plus a low-pass ``eps2d * I``; a radius of three standard deviations along
the major axis; culling outside ``(near_plane, far_plane)`` and outside the image.

Unlike gsplat's reference, every division is guarded so that Gaussians behind the camera, on the
camera plane or with degenerate covariances give finite values and finite (zero) gradients.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

# Radii above this are clamped before the integer conversion (a Gaussian that large covers any
# image; the clamp only keeps the int32 cast defined).
_MAX_RADIUS = 1.0e7


@dataclass
class Projection:
    """Per-camera, per-Gaussian result of :func:`project_gaussians` (gsplat's outputs)."""

    means2d: Tensor  # [C, N, 2] pixel coordinates (pixel centres at +0.5)
    conics: Tensor  # [C, N, 3] inverse 2D covariance (a, b, c): [[a, b], [b, c]]
    depths: Tensor  # [C, N] camera-space z
    radii: Tensor  # [C, N] int32, 0 where culled
    covars2d: Tensor  # [C, N, 3] blurred 2D covariance (xx, xy, yy)
    compensations: Optional[Tensor] = None  # [C, N] sqrt(det(cov) / det(cov + eps2d I))

    @property
    def valid(self) -> Tensor:  # [C, N] bool
        """Gaussians that survive culling (``radii > 0``)."""
        return self.radii > 0


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices from wxyz quaternions (normalised here; a zero quaternion gives I).

    quats: [..., 4]; returns [..., 3, 3].
    """
    # Normalising with a floor keeps degenerate (zero) quaternions finite in value and gradient.
    norm = torch.linalg.vector_norm(quats, dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = torch.unbind(quats / norm, dim=-1)
    rot = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return rot.reshape(quats.shape[:-1] + (3, 3))


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World-space covariance ``R S S^T R^T``.

    quats: [N, 4] wxyz; scales: [N, 3] activated; returns [N, 3, 3].
    """
    m = quat_to_rotmat(quats) * scales[..., None, :]
    return m @ m.transpose(-1, -2)


def project_gaussians(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4] wxyz
    scales: Tensor,  # [N, 3]
    viewmats: Tensor,  # [C, 4, 4] world-to-camera
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    *,
    eps2d: float = 0.3,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
    calc_compensations: bool = False,
    covars: Optional[Tensor] = None,  # [N, 3, 3] overrides quats/scales when given
) -> Projection:
    """Project 3D Gaussians to C pinhole cameras (gsplat 1.4.0 ``fully_fused_projection``).

    Returns a :class:`Projection` with means2d [C,N,2], conics [C,N,3], depths [C,N] and
    int32 radii [C,N] (0 for culled Gaussians: depth outside (near, far), radius <= radius_clip,
    or 3-sigma box outside the image). Differentiable w.r.t. means, quats, scales, viewmats.
    """
    if covars is None:
        covars = covariance_3d(quats, scales)
    rot = viewmats[:, :3, :3]  # [C, 3, 3]
    trans = viewmats[:, :3, 3]  # [C, 3]
    means_c = torch.einsum("cij,nj->cni", rot, means) + trans[:, None, :]  # [C, N, 3]
    covars_c = torch.einsum("cij,njk,clk->cnil", rot, covars, rot)  # [C, N, 3, 3]

    tx, ty, tz = torch.unbind(means_c, dim=-1)  # [C, N]
    depth_ok = (tz > near_plane) & (tz < far_plane)
    # Culled Gaussians get a dummy depth so that no division below can produce inf/NaN (the
    # double-where keeps their gradients exactly zero).
    tz_safe = torch.where(depth_ok, tz, torch.ones_like(tz))
    fx = Ks[:, 0, 0, None]
    fy = Ks[:, 1, 1, None]
    cx = Ks[:, 0, 2, None]
    cy = Ks[:, 1, 2, None]
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    u = torch.minimum(torch.maximum(tx / tz_safe, -lim_x_neg), lim_x_pos)
    v = torch.minimum(torch.maximum(ty / tz_safe, -lim_y_neg), lim_y_pos)

    # Jacobian rows: [fx/z, 0, -fx*x/z^2] and [0, fy/z, -fy*y/z^2] with x/z, y/z clamped.
    zero = torch.zeros_like(tz_safe)
    jac = torch.stack(
        [fx / tz_safe, zero, -fx * u / tz_safe, zero, fy / tz_safe, -fy * v / tz_safe], dim=-1
    ).reshape(tz.shape + (2, 3))
    cov2d = jac @ covars_c @ jac.transpose(-1, -2)  # [C, N, 2, 2]
    c_xx = cov2d[..., 0, 0]
    c_xy = 0.5 * (cov2d[..., 0, 1] + cov2d[..., 1, 0])
    c_yy = cov2d[..., 1, 1]
    det_orig = c_xx * c_yy - c_xy * c_xy
    c_xx = c_xx + eps2d
    c_yy = c_yy + eps2d
    det = (c_xx * c_yy - c_xy * c_xy).clamp_min(1e-10)
    conics = torch.stack([c_yy / det, -c_xy / det, c_xx / det], dim=-1)

    means2d = torch.stack(
        [fx * tx / tz_safe + cx, fy * ty / tz_safe + cy], dim=-1
    )  # [C, N, 2]

    with torch.no_grad():
        b = 0.5 * (c_xx + c_yy)
        v1 = b + torch.sqrt(torch.clamp(b * b - det, min=0.01))
        radius = torch.ceil(3.0 * torch.sqrt(v1)).clamp(max=_MAX_RADIUS)
        radius = torch.nan_to_num(radius, nan=0.0, posinf=_MAX_RADIUS)
        valid = depth_ok & (radius > radius_clip)
        inside = (
            (means2d[..., 0] + radius > 0)
            & (means2d[..., 0] - radius < width)
            & (means2d[..., 1] + radius > 0)
            & (means2d[..., 1] - radius < height)
        )
        radii = torch.where(valid & inside, radius, torch.zeros_like(radius)).to(torch.int32)

    compensations = None
    if calc_compensations:
        compensations = torch.sqrt(torch.clamp(det_orig / det, min=0.0))
    return Projection(
        means2d=means2d,
        conics=conics,
        depths=tz,
        radii=radii,
        covars2d=torch.stack([c_xx, c_xy, c_yy], dim=-1),
        compensations=compensations,
    )
