"""Camera images and instance masks of the synthetic street by ray casting.

Lighting: sky ambient plus a sun with cast shadows (shadow rays), a sky reflection on glass and a
small highlight on car paint; distant surfaces fade into the horizon haze. Each pixel averages
`supersample`^2 rays (anti-aliasing); its instance id is the one most of its rays hit.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from idsplat_ns.data.camera import RollingShutter
from idsplat_ns.data.rolling_shutter import is_rolling, line_times
from idsplat_ns.data.synthetic import materials as mat
from idsplat_ns.data.synthetic import textures
from idsplat_ns.data.synthetic.raycast import RayCaster, RayHits
from idsplat_ns.data.synthetic.rig import PinholeCamera

HORIZON = np.array([0.80, 0.85, 0.90])
ZENITH = np.array([0.30, 0.50, 0.82])
SUN_COLOR = np.array([1.0, 0.97, 0.90])
HAZE_DISTANCE = 320.0
"""Distance (m) at which 63% of a surface's colour has faded into the horizon haze."""


def sky_gradient(directions: np.ndarray) -> np.ndarray:
    """Cloudless sky colour [N, 3] for unit directions [N, 3] (what glass reflects)."""
    up = np.clip(directions[:, 2], 0.0, 1.0)
    return HORIZON + (ZENITH - HORIZON) * (up**0.55)[:, None]


def sky(directions: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """Sky colour [N, 3] for unit view directions [N, 3] (local frame): gradient, clouds, sun glow."""
    colour = sky_gradient(directions)
    # Clouds on a plane at infinity: a function of the direction only (consistent across views).
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = directions[:, :2] / np.maximum(directions[:, 2:3], 0.03)
    cloud = textures.fbm(uv * 1.6, 201, octaves=4)
    cover = np.clip((cloud - 0.5) / 0.25, 0.0, 1.0) * np.clip(directions[:, 2] * 6.0, 0.0, 1.0)
    colour = colour + (np.array([0.96, 0.96, 0.97]) - colour) * (0.85 * cover)[:, None]
    glow = np.clip(directions @ sun, 0.0, 1.0) ** 48
    return colour + 0.35 * glow[:, None] * SUN_COLOR


def shade(caster: RayCaster, hits: RayHits, directions: np.ndarray, times: np.ndarray, shadows: bool) -> np.ndarray:
    """Colour [N, 3] of every ray (sky where nothing was hit)."""
    sun = caster.world.sun_direction
    rgb = np.zeros((len(directions), 3))
    miss = ~hits.hit
    rgb[miss] = sky(directions[miss], sun)
    rows = np.flatnonzero(hits.hit)
    if len(rows) == 0:
        return rgb
    surf = textures.evaluate(caster, hits, rows)
    n = hits.normal[rows]
    d = directions[rows]
    # Surfaces seen from behind (never for closed shapes) are lit like their front.
    n = np.where(((n * d).sum(1) > 0)[:, None], -n, n)
    lit = np.clip(n @ sun, 0.0, 1.0)
    if shadows:
        facing = np.flatnonzero(lit > 0)
        origins = hits.point[rows[facing]] + 2e-3 * n[facing] + 2e-3 * sun
        blocked = caster.occluded(origins, sun, times[rows[facing]])
        lit[facing[blocked]] = 0.0
    ambient = 0.42 + 0.12 * n[:, 2]
    colour = surf.albedo * (ambient[:, None] * np.array([0.92, 0.95, 1.0]) + 0.72 * lit[:, None] * SUN_COLOR)
    # Glass mirrors the sky (or the dark street below the horizon), stronger at grazing angles.
    cos_i = np.abs((n * d).sum(1))
    refl_dir = d - 2.0 * (d * n).sum(1, keepdims=True) * n
    env = np.where((refl_dir[:, 2] > 0)[:, None], sky_gradient(refl_dir), np.array([0.22, 0.22, 0.22]))
    fresnel = 0.12 + 0.55 * (1.0 - cos_i) ** 4
    colour = np.where(surf.glass[:, None], colour + fresnel[:, None] * env, colour)
    # Paint and glass highlights of the sun.
    material = caster.part_material[hits.part[rows]]
    shiny = surf.glass | (material == mat.CAR_BODY) | (material == mat.BUS_BODY)
    spec = np.clip((refl_dir @ sun), 0.0, 1.0) ** 60 * (lit > 0)
    colour = colour + np.where(shiny, 0.6 * spec, 0.0)[:, None] * SUN_COLOR
    colour = np.where(surf.emissive[:, None], surf.albedo, colour)
    haze = 1.0 - np.exp(-hits.distance[rows] / HAZE_DISTANCE)
    rgb[rows] = colour + (HORIZON - colour) * haze[:, None]
    return rgb


def pixel_rays(camera: PinholeCamera, supersample: int) -> np.ndarray:
    """Unit ray directions in the camera frame [H, W, S*S, 3] through sub-pixel sample points."""
    offs = (np.arange(supersample) + 0.5) / supersample
    u = np.arange(camera.width)[:, None] + offs[None, :]  # [W, S]
    v = np.arange(camera.height)[:, None] + offs[None, :]  # [H, S]
    x = (u - camera.cx) / camera.fx
    y = (v - camera.cy) / camera.fy
    xs = np.broadcast_to(x[None, :, None, :], (camera.height, camera.width, supersample, supersample))
    ys = np.broadcast_to(y[:, None, :, None], (camera.height, camera.width, supersample, supersample))
    d = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(camera.height, camera.width, supersample**2, 3)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _mode(values: np.ndarray) -> np.ndarray:
    """Most frequent value along the last axis of `values` [..., K] (ties: the first sample)."""
    counts = (values[..., :, None] == values[..., None, :]).sum(-1)
    pick = counts.argmax(-1)
    return np.take_along_axis(values, pick[..., None], -1)[..., 0]


def render_camera(
    caster: RayCaster, camera: PinholeCamera, time: float, supersample: int = 1, shadows: bool = True,
    shutter: Optional[RollingShutter] = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image uint8 [H, W, 3], instance ids uint16 [H, W] and depth (z, metres) float32 [H, W] at `time`.

    Global shutter (``shutter`` None or readout 0): the camera pose is the ego pose at `time`.
    Rolling shutter: every line (its sub-pixel rays included) is cast at its own time
    (:func:`idsplat_ns.data.rolling_shutter.line_times`, `time` is the centre line's), from the
    camera pose at that time, and meets the road users where they are then. Depth is inf on the sky.
    """
    d_cam = pixel_rays(camera, supersample)
    h, w, k, _ = d_cam.shape
    if is_rolling(shutter):
        dirs, origins, times = _rolling_rays(caster, camera, time, shutter, d_cam)
    else:
        rot, pos = camera.pose(caster.world, time)
        dirs = d_cam.reshape(-1, 3) @ rot.T
        origins = np.broadcast_to(pos, dirs.shape)
        times = np.full(len(dirs), time)
    hits = caster.cast(origins, dirs, times)
    rgb = shade(caster, hits, dirs, times, shadows).reshape(h, w, k, 3).mean(2)
    rgb = np.clip(rgb * camera.gain, 0.0, 1.0)
    image = np.round(rgb * 255.0).astype(np.uint8)
    inst = np.where(hits.hit, caster.instance_of_object[np.maximum(hits.obj, 0)], 0).reshape(h, w, k)
    instance = _mode(inst).astype(np.uint16)
    z = (hits.distance * d_cam.reshape(-1, 3)[:, 2]).reshape(h, w, k).mean(2)
    return image, instance, z.astype(np.float32)


def _rolling_rays(
    caster: RayCaster, camera: PinholeCamera, time: float, shutter: RollingShutter, d_cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Street-frame directions, origins and times [N, 3], [N, 3], [N] of the rays `d_cam`
    [H, W, K, 3] when each line is exposed at its own time, from the camera pose at that time."""
    h, w, k, _ = d_cam.shape
    axis, tau = line_times(shutter, camera.width, camera.height)
    rot, pos = camera.poses(caster.world, time + tau)  # [L, 3, 3], [L, 3]
    line = np.broadcast_to((np.arange(h)[:, None] if axis == 1 else np.arange(w)[None, :])[..., None], (h, w, k))
    line = line.reshape(-1)
    dirs = np.einsum("nij,nj->ni", rot[line], d_cam.reshape(-1, 3))
    return dirs, pos[line], time + tau[line]
