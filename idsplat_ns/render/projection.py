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

from .rolling_shutter import CameraMotion, shift_camera_points

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


def _rotation_entries(quats: Tensor) -> list:
    """The nine entries (row-major, each [...]) of the rotation of wxyz quaternions [..., 4]."""
    # Normalising with a floor keeps degenerate (zero) quaternions finite in value and gradient.
    inv_norm = 1.0 / torch.linalg.vector_norm(quats, dim=-1).clamp_min(1e-12)
    w, x, y, z = (q * inv_norm for q in torch.unbind(quats, dim=-1))
    return [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices from wxyz quaternions (normalised here; a zero quaternion gives I).

    quats: [..., 4]; returns [..., 3, 3].
    """
    return torch.stack(_rotation_entries(quats), dim=-1).reshape(quats.shape[:-1] + (3, 3))


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
    motion: Optional["CameraMotion"] = None,
) -> Projection:
    """Project 3D Gaussians to C pinhole cameras (gsplat 1.4.0 ``fully_fused_projection``).

    Returns a :class:`Projection` with means2d [C,N,2], conics [C,N,3], depths [C,N] and
    int32 radii [C,N] (0 for culled Gaussians: depth outside (near, far), radius <= radius_clip,
    or 3-sigma box outside the image). Differentiable w.r.t. means, quats, scales, viewmats.
    ``motion``: rolling shutter; each mean is moved to the time its line is exposed
    (:mod:`idsplat_ns.render.rolling_shutter`). None, or a global timing, is the plain projection.
    """
    # Computed in float64 and returned in the input dtype: the camera gradient sums terms of
    # size ~1e3 per Gaussian that cancel to ~1 (float32 rounding there is as large as the test
    # tolerances), and written per element rather than as batched 3x3 products (several times
    # slower on CPU); in float64 this is still cheaper than the float32 batched products.
    out_dtype = means.dtype
    f64 = torch.float64
    rot = viewmats[:, :3, :3].to(f64)  # [C, 3, 3]
    trans = viewmats[:, :3, 3].to(f64)  # [C, 3]
    r = [[rot[:, i, k, None] for k in range(3)] for i in range(3)]  # [C, 1] entries
    mx, my, mz = means.to(f64).unbind(-1)  # [N]
    tx, ty, tz = (r[i][0] * mx + r[i][1] * my + r[i][2] * mz + trans[:, i, None] for i in range(3))  # [C, N]
    if motion is not None and not motion.is_global():
        tx, ty, tz, _ = shift_camera_points(tx, ty, tz, rot, Ks.to(f64), motion, width, height)
    depth_ok = (tz > near_plane) & (tz < far_plane)
    # Culled Gaussians get a dummy depth so that no division below can produce inf/NaN (the
    # double-where keeps their gradients exactly zero).
    tz_safe = torch.where(depth_ok, tz, torch.ones_like(tz))
    Ks = Ks.to(f64)
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
    inv_z = 1.0 / tz_safe
    u = torch.minimum(torch.maximum(tx * inv_z, -lim_x_neg), lim_x_pos)
    v = torch.minimum(torch.maximum(ty * inv_z, -lim_y_neg), lim_y_pos)

    # Jacobian rows: [fx/z, 0, -fx*x/z^2] and [0, fy/z, -fy*y/z^2] with x/z, y/z clamped.
    jx = fx * inv_z  # [C, N]
    jy = fy * inv_z
    jxz = -jx * u
    jyz = -jy * v
    if covars is None:
        # cov2d = (J R_cam M)(J R_cam M)^T with M = R(q) diag(s): the two rows of J R_cam M.
        q = _rotation_entries(quats.to(f64))  # 9 x [N]
        sx, sy, sz = scales.to(f64).unbind(-1)
        m = [[q[3 * k] * sx, q[3 * k + 1] * sy, q[3 * k + 2] * sz] for k in range(3)]  # M[k][j], [N]
        ax = [jx * r[0][k] + jxz * r[2][k] for k in range(3)]  # row x of J R_cam, [C, N]
        ay = [jy * r[1][k] + jyz * r[2][k] for k in range(3)]
        row_x = [ax[0] * m[0][j] + ax[1] * m[1][j] + ax[2] * m[2][j] for j in range(3)]
        row_y = [ay[0] * m[0][j] + ay[1] * m[1][j] + ay[2] * m[2][j] for j in range(3)]
        c_xx = row_x[0] * row_x[0] + row_x[1] * row_x[1] + row_x[2] * row_x[2]
        c_xy = row_x[0] * row_y[0] + row_x[1] * row_y[1] + row_x[2] * row_y[2]
        c_yy = row_y[0] * row_y[0] + row_y[1] * row_y[1] + row_y[2] * row_y[2]
    else:
        cov_c = torch.einsum("cij,njk,clk->cnil", rot, covars.to(f64), rot)  # [C, N, 3, 3]
        s00, s01, s02 = cov_c[..., 0, 0], cov_c[..., 0, 1], cov_c[..., 0, 2]
        s11, s12, s22 = cov_c[..., 1, 1], cov_c[..., 1, 2], cov_c[..., 2, 2]
        c_xx = jx * jx * s00 + 2 * jx * jxz * s02 + jxz * jxz * s22
        c_xy = jx * jy * s01 + jx * jyz * s02 + jxz * jy * s12 + jxz * jyz * s22
        c_yy = jy * jy * s11 + 2 * jy * jyz * s12 + jyz * jyz * s22
    det_orig = c_xx * c_yy - c_xy * c_xy
    c_xx = c_xx + eps2d
    c_yy = c_yy + eps2d
    det = (c_xx * c_yy - c_xy * c_xy).clamp_min(1e-10)
    inv_det = 1.0 / det
    conics = torch.stack([c_yy * inv_det, -c_xy * inv_det, c_xx * inv_det], dim=-1)

    means2d = torch.stack([fx * tx * inv_z + cx, fy * ty * inv_z + cy], dim=-1)  # [C, N, 2]

    means2d = means2d.to(out_dtype)
    with torch.no_grad():
        # Radii from the covariance in the output dtype, as gsplat computes them (identical
        # integer radii; the ceil is sensitive to the last bit).
        r_xx, r_xy, r_yy = c_xx.to(out_dtype), c_xy.to(out_dtype), c_yy.to(out_dtype)
        b = 0.5 * (r_xx + r_yy)
        v1 = b + torch.sqrt(torch.clamp(b * b - (r_xx * r_yy - r_xy * r_xy).clamp_min(1e-10), min=0.01))
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
        compensations = compensations.to(out_dtype)
    return Projection(
        means2d=means2d,
        conics=conics.to(out_dtype),
        depths=tz.to(out_dtype),
        radii=radii,
        covars2d=torch.stack([c_xx, c_xy, c_yy], dim=-1).to(out_dtype),
        compensations=compensations,
    )
