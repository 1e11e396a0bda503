"""Non-rigid motion of chosen instances (pedestrians, cyclists): swinging legs and arms, pedalling.

The paper models every instance as a rigid body. Here an instance of a deformable class also gets
a small time-dependent offset of each Gaussian's mean, in its canonical frame, before its rigid
pose moves it to the world:

    mu_i(t) = T_z(t) (mu_i + f([gamma(mu_i), c_z(t)]))

* ``c_z(t)`` is a latent code of instance ``z`` (``latent_dim`` numbers), one per trajectory step
  and interpolated linearly between the steps, like the rigid poses: a held-out time between two
  training steps gets the code between theirs.
* ``gamma`` is a sine/cosine encoding of the canonical position, so that legs and torso can move
  differently; ``f`` is a two-layer MLP shared by all deformable instances.
* The last layer starts at zero: training starts from the rigid model and deforms only where the
  images ask for it.

Why a field and not per-Gaussian coefficients: MCMC relocates, adds and removes Gaussians every
few steps; a function of the canonical position follows them with nothing to copy, and its size
does not grow with the Gaussian count. Orientations and scales stay rigid (first order), and the
rolling shutter sees the rigid velocity only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Tuple

import numpy as np
import torch
from torch import Tensor, nn


@dataclass
class DeformationConfig:
    """Non-rigid instances (off by default: see docs/reports/2026-11-27-deformation.md for what it measured)."""

    enabled: bool = False
    """Give the instances of ``classes`` a time-dependent deformation (False: every instance rigid,
    as the paper)."""
    classes: Tuple[str, ...] = ("pedestrian", "cyclist")
    """Instance classes that deform (an instance's class: its mask label, its annotation in oracle
    mode, or its size and speed)."""
    latent_dim: int = 8
    """Numbers per instance and trajectory step in the latent code."""
    hidden: int = 64
    """Width of the two hidden layers of the offset MLP."""
    position_freqs: int = 4
    """Sine/cosine frequencies (2^0 .. 2^(n-1) per metre) encoding the canonical position."""


def position_encoding(x: Tensor, num_freqs: int) -> Tensor:  # x: [M, 3] metres -> [M, 3 + 6 * num_freqs]
    """``[x, sin(2^k x), cos(2^k x)]`` for k < ``num_freqs`` (periods from 2 pi m down)."""
    if num_freqs == 0:
        return x
    freqs = 2.0 ** torch.arange(num_freqs, dtype=x.dtype, device=x.device)  # [K]
    ang = (x[:, None, :] * freqs[None, :, None]).reshape(x.shape[0], -1)  # [M, 3K]
    return torch.cat([x, torch.sin(ang), torch.cos(ang)], dim=1)


def interpolate_codes(codes: Tensor, step_times: Tensor, t: float | Tensor) -> Tensor:
    """Codes [D, F, C] at time ``t`` [D, C]: linear between the bracketing steps (``step_times``
    [F], increasing, float64), the end step's code outside them."""
    F = step_times.shape[0]
    tv = t.detach().reshape(()).to(step_times) if isinstance(t, Tensor) else torch.tensor(float(t), dtype=step_times.dtype,
                                                                                          device=step_times.device)
    if F == 1:
        return codes[:, 0]
    k0 = (torch.searchsorted(step_times, tv.reshape(1), right=True) - 1).clamp(0, F - 2)
    t0, t1 = step_times[k0], step_times[k0 + 1]
    w = ((tv - t0) / (t1 - t0)).clamp(0.0, 1.0).to(codes.dtype)  # [1]
    return codes[:, k0[0]] * (1 - w) + codes[:, k0[0] + 1] * w


class InstanceDeformation(nn.Module):
    """Per-Gaussian mean offsets [M, 3] (canonical frame) for the instances in ``instance_ids``."""

    def __init__(self, step_times: np.ndarray, instance_ids: np.ndarray, latent_dim: int = 8, hidden: int = 64,
                 position_freqs: int = 4, seed: int = 0) -> None:
        """``step_times`` [F] seconds, the trajectory steps; ``instance_ids`` [D] the deformable
        instances (>= 1). The codes start as small random numbers (distinct instances and steps),
        the MLP's last layer at zero (no offset)."""
        super().__init__()
        step_times = np.asarray(step_times, dtype=np.float64)
        ids = np.asarray(instance_ids, dtype=np.int64).reshape(-1)
        if len(step_times) == 0 or np.any(np.diff(step_times) <= 0):
            raise ValueError("InstanceDeformation: step_times must be non-empty and strictly increasing")
        if np.any(ids < 1) or len(np.unique(ids)) != len(ids):
            raise ValueError("InstanceDeformation: instance ids must be unique and >= 1 (0 is the background)")
        self.position_freqs = int(position_freqs)
        gen = torch.Generator().manual_seed(seed)
        self.register_buffer("step_times", torch.from_numpy(step_times))
        self.register_buffer("instance_ids", torch.from_numpy(ids))
        self.codes = nn.Parameter(0.1 * torch.randn(len(ids), len(step_times), latent_dim, generator=gen))
        # The layers draw their initial weights from torch's global generator: seeded and restored
        # here, so that the field starts the same whatever ran before.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.mlp = nn.Sequential(
                nn.Linear(3 + 6 * self.position_freqs + latent_dim, hidden), nn.ReLU(),
                nn.Linear(hidden, hidden), nn.ReLU(),
                nn.Linear(hidden, 3),
            )
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    @classmethod
    def placeholder(cls, num_instances: int, num_steps: int, latent_dim: int, hidden: int,
                    position_freqs: int) -> "InstanceDeformation":
        """The shapes of a checkpoint whose state dict replaces the values (ns-eval, the viewer)."""
        return cls(np.arange(max(num_steps, 1), dtype=np.float64), np.arange(1, num_instances + 1), latent_dim, hidden,
                   position_freqs)

    @property
    def num_instances(self) -> int:
        return int(self.instance_ids.shape[0])

    def offsets(self, means: Tensor, instance_ids: Tensor, t: float | Tensor) -> Tensor:
        """Offsets [M, 3] of ``means`` [M, 3] (canonical frame of each one's instance, ``instance_ids``
        [M]) at time ``t`` seconds; zero for Gaussians of other instances and of the background."""
        out = torch.zeros_like(means)
        if self.num_instances == 0 or means.shape[0] == 0:
            return out
        size = int(max(int(instance_ids.max()), int(self.instance_ids.max()))) + 1
        lut = torch.full((size,), -1, dtype=torch.int64, device=means.device)
        lut[self.instance_ids.to(means.device)] = torch.arange(self.num_instances, device=means.device)
        row = lut[instance_ids.long().clamp_min(0)]
        sel = torch.nonzero(row >= 0).squeeze(-1)
        if sel.numel() == 0:
            return out
        code = interpolate_codes(self.codes, self.step_times, t).to(means.dtype)  # [D, C]
        x = torch.cat([position_encoding(means[sel], self.position_freqs), code[row[sel]]], dim=1)
        return out.index_put((sel,), self.mlp(x))


def deformable_instance_ids(tracks, classes: Tuple[str, ...]) -> list[int]:
    """IDs of the dynamic instances of ``tracks`` (InstanceTracks) whose class is in ``classes``."""
    return [int(i.instance_id) for i in tracks.instances if i.category in classes]
