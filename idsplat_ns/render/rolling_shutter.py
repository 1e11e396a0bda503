"""Rolling shutter in camera rendering: each Gaussian is drawn where it is when its line is exposed.

First-order model, as in SplatAD. Each Gaussian mean has a camera-frame velocity ``v_c``, made
of the camera's motion (linear and angular velocity) and the Gaussian's own motion (its
instance's). A pixel ``(u, v)`` is exposed ``tau = t0 + du u + dv v`` seconds after the camera's
time (:class:`ShutterTiming`; conventions in :mod:`idsplat_ns.data.rolling_shutter`). The mean
is moved to ``p_c + v_c tau``, with ``tau`` solved for the line it lands on. The projected mean
moves linearly, ``m(tau) = m + m' tau``, with ``m'`` the pixel velocity (the perspective
Jacobian times ``v_c``). So ``tau = t0 + a . m(tau)`` gives

    tau = (t0 + a . m) / (1 - a . m'),        a = (du, dv).

``tau`` is clamped to the image's exposure window, so a Gaussian off screen takes the time of the
nearest edge line. The 3D mean is then shifted and projected as usual. Its shape is not sheared,
and ``1 - a . m'`` is floored at 0.1, which only a Gaussian sweeping across the image almost as
fast as the readout reaches.

Camera-frame velocity of a world point ``p`` with velocity ``v`` (camera ``R_cw``, centre ``c``,
world linear and angular velocities ``v_cam`` and ``w``):

    v_c = R_cw (v - v_cam) - (R_cw w) x p_c.

It comes from differentiating ``p_c(t) = R_cw(t) (p(t) - c(t))`` with ``R_wc(t) = exp(w t) R_wc``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

_MIN_DENOMINATOR = 0.1  # floor of 1 - a . m' (see the module doc)


@dataclass
class ShutterTiming:
    """Per camera, the exposure time of pixel ``(u, v)`` relative to the camera's time: ``t0 + du u + dv v``."""

    t0: Tensor  # [C] seconds
    du: Tensor  # [C] seconds per pixel along x
    dv: Tensor  # [C] seconds per pixel along y

    @classmethod
    def from_planes(cls, planes, device=None) -> "ShutterTiming":
        """From ``(t0, du, dv)`` tuples, one per camera (:func:`idsplat_ns.data.rolling_shutter.time_plane`)."""
        t = torch.tensor([list(p) for p in planes], dtype=torch.float64, device=device).reshape(-1, 3)
        return cls(t[:, 0], t[:, 1], t[:, 2])

    def is_global(self) -> bool:
        """Every pixel at the camera's time (all coefficients zero)."""
        return not bool(torch.any(self.t0 != 0) | torch.any(self.du != 0) | torch.any(self.dv != 0))

    def bounds(self, width: int, height: int) -> tuple[Tensor, Tensor]:
        """Earliest and latest exposure time [C] over the image (at its corners)."""
        corners = torch.stack([self.t0 + self.du * u + self.dv * v for u in (0.0, width) for v in (0.0, height)], -1)
        return corners.amin(-1), corners.amax(-1)


@dataclass
class CameraMotion:
    """What a rolling-shutter render needs besides the poses at the camera's time."""

    timing: ShutterTiming
    """Exposure time of each pixel."""
    linear_velocity: Tensor  # [C, 3]
    """World-frame velocity of each camera centre, m/s."""
    angular_velocity: Tensor  # [C, 3]
    """World-frame angular velocity of each camera, rad/s."""
    velocities: Optional[Tensor] = None  # [N, 3]
    """World-frame velocity of each Gaussian mean, m/s (None: all static)."""

    def is_global(self) -> bool:
        return self.timing.is_global()


def shift_camera_points(
    tx: Tensor,  # [C, N] camera-frame x of the means (float64)
    ty: Tensor,  # [C, N]
    tz: Tensor,  # [C, N]
    rot: Tensor,  # [C, 3, 3] world-to-camera rotation (float64)
    Ks: Tensor,  # [C, 3, 3] (float64)
    motion: CameraMotion,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Camera-frame means moved to their exposure time: ``(tx, ty, tz, tau)``, each [C, N].

    Differentiable with respect to the means, the rotation, the velocities and the intrinsics.
    """
    f64 = torch.float64
    dev = tx.device
    # Per component, as in the projection: [C, N] elementwise products beat batched 3x3 ones on CPU.
    v_cam = motion.linear_velocity.to(device=dev, dtype=f64)  # [C, 3]
    if motion.velocities is None:
        rel = [-v_cam[:, k, None] for k in range(3)]  # [C, 1]
    else:
        vel = motion.velocities.to(f64)
        rel = [vel[None, :, k] - v_cam[:, k, None] for k in range(3)]  # [C, N]
    w_c = torch.einsum("cij,cj->ci", rot, motion.angular_velocity.to(device=dev, dtype=f64))  # [C, 3]
    wx, wy, wz = (w_c[:, k, None] for k in range(3))
    r = [[rot[:, i, k, None] for k in range(3)] for i in range(3)]
    vx, vy, vz = (r[i][0] * rel[0] + r[i][1] * rel[1] + r[i][2] * rel[2] for i in range(3))
    vx, vy, vz = vx - (wy * tz - wz * ty), vy - (wz * tx - wx * tz), vz - (wx * ty - wy * tx)  # - w_c x p_c
    # Pixel position and velocity; points at or behind the camera plane get a dummy depth (they
    # are culled later, and their shift must stay finite).
    z = torch.where(tz > 1e-6, tz, torch.ones_like(tz))
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    xn, yn = tx / z, ty / z
    u, v = fx * xn + cx, fy * yn + cy
    du_dt, dv_dt = fx * (vx - xn * vz) / z, fy * (vy - yn * vz) / z
    timing = motion.timing
    t0, a_u, a_v = (x.to(device=tx.device, dtype=f64)[:, None] for x in (timing.t0, timing.du, timing.dv))
    denom = (1.0 - a_u * du_dt - a_v * dv_dt).clamp_min(_MIN_DENOMINATOR)
    tau = (t0 + a_u * u + a_v * v) / denom
    lo, hi = timing.bounds(width, height)
    tau = torch.maximum(torch.minimum(tau, hi.to(device=tx.device, dtype=f64)[:, None]),
                        lo.to(device=tx.device, dtype=f64)[:, None])
    return tx + vx * tau, ty + vy * tau, tz + vz * tau, tau


def shifted_world_means(
    means: Tensor,  # [N, 3]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    motion: CameraMotion,
    width: int,
    height: int,
) -> Tensor:  # [C, N, 3] in the dtype of means
    """World means moved to their exposure time in each camera, for backends that take 3D means
    (gsplat): ``R_cw^T (p_c(tau) - T)``."""
    f64 = torch.float64
    rot, trans = viewmats[:, :3, :3].to(f64), viewmats[:, :3, 3].to(f64)
    p_c = torch.einsum("cij,nj->cni", rot, means.to(f64)) + trans[:, None, :]
    tx, ty, tz, _ = shift_camera_points(p_c[..., 0], p_c[..., 1], p_c[..., 2], rot, Ks.to(f64), motion, width, height)
    shifted = torch.stack([tx, ty, tz], -1) - trans[:, None, :]
    return torch.einsum("cji,cnj->cni", rot, shifted).to(means.dtype)
