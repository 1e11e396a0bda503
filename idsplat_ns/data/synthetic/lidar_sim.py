"""Spinning 64-beam lidar sweeps of the synthetic street.

One sweep is one full rotation around the frame time (from `frame_time - period/2` to
`frame_time + period/2`). Column j (all 64 beams fire together) points at sensor azimuth
`-pi/2 + 2 pi j / steps` (counter-clockwise from the sensor's x = right, so the seam is behind the
car and the front is at mid-sweep), at time `frame_time - period/2 + j * period / steps`. Every ray
starts from the sensor pose at its own time: the ego moves during the sweep (rolling scan).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idsplat_ns.data.synthetic import textures
from idsplat_ns.data.synthetic.raycast import RayCaster
from idsplat_ns.data.synthetic.rig import beam_elevations, lidar_pose


@dataclass
class LidarSweep:
    """One sweep, local street frame. Returns and non-returns are disjoint sets of rays."""

    points: np.ndarray  # [P, 3] returned points (with range noise)
    intensity: np.ndarray  # [P] 0..255
    times: np.ndarray  # [P] seconds (same clock as the frame time)
    origins: np.ndarray  # [P, 3] sensor position when each returned ray fired
    part: np.ndarray  # [P] part index that was hit (for tests and debugging)
    miss_origins: np.ndarray  # [M, 3] rays that returned nothing: sensor position
    miss_directions: np.ndarray  # [M, 3] unit directions
    miss_times: np.ndarray  # [M] seconds


def sweep_rays(caster: RayCaster, frame_time: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origins [N, 3], unit directions [N, 3] and times [N] of one sweep, column-major (column, beam)."""
    cfg = caster.world.config
    steps = cfg.lidar.azimuth_steps
    period = 1.0 / cfg.frame_rate
    col = np.arange(steps)
    col_times = frame_time - period / 2 + col * period / steps
    azimuth = -np.pi / 2 + 2 * np.pi * col / steps
    elev = np.radians(beam_elevations(cfg.lidar.elevation_min_deg, cfg.lidar.elevation_max_deg))
    az, el = np.meshgrid(azimuth, elev, indexing="ij")  # [steps, 64]
    d_sensor = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    rot, pos = lidar_pose(caster.world, col_times)
    d = np.einsum("cij,cbj->cbi", rot, d_sensor).reshape(-1, 3)
    n_beams = len(elev)
    origins = np.repeat(pos, n_beams, axis=0)
    times = np.repeat(col_times, n_beams)
    return origins, d, times


def simulate_sweep(caster: RayCaster, frame_time: float, rng: np.random.Generator) -> LidarSweep:
    """Cast one sweep: intensity from material, Gaussian range noise, drop-outs, max range."""
    cfg = caster.world.config.lidar
    origins, dirs, times = sweep_rays(caster, frame_time)
    hits = caster.cast(origins, dirs, times)
    n = len(dirs)
    returned = hits.hit & (hits.distance <= cfg.max_range)
    rows = np.flatnonzero(returned)
    surf = textures.evaluate(caster, hits, rows)
    drop_p = np.where(surf.glass, cfg.glass_dropout_prob, cfg.dropout_prob)
    # Draw every random number for every ray, so a sweep's noise does not depend on what it hit.
    u_drop = rng.random(n)
    noise = rng.normal(0.0, cfg.range_noise_std, n)
    i_noise = rng.normal(0.0, 2.0, n)
    keep = u_drop[rows] >= drop_p
    rows = rows[keep]
    cos_i = np.abs((hits.normal[rows] * dirs[rows]).sum(1))
    falloff = np.where(surf.retro[keep], 1.0, 0.3 + 0.7 * cos_i)
    intensity = np.clip(surf.reflectivity[keep] * falloff + i_noise[rows], 0.0, 255.0)
    rng_noisy = hits.distance[rows] + noise[rows]
    points = origins[rows] + rng_noisy[:, None] * dirs[rows]
    miss = np.ones(n, bool)
    miss[rows] = False
    return LidarSweep(
        points=points,
        intensity=intensity,
        times=times[rows],
        origins=origins[rows],
        part=hits.part[rows],
        miss_origins=origins[miss],
        miss_directions=dirs[miss],
        miss_times=times[miss],
    )
