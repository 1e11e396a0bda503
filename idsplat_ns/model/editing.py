"""Instance editing on a trained scene's tensors: remove, move, re-time and duplicate instances.

The edits work on the scene model's state dict (the tensors of :class:`GaussianSet` and
:class:`InstanceTrajectories`), never on a live nerfstudio model, so that an edited scene is
again an ordinary checkpoint that every loader reads. No nerfstudio import here.

Conventions (docs/conventions.md): a trajectory row maps instance ``z``'s canonical frame to the
world at each step, ``T = [R | p]``; the canonical frame has x forward, y left, z up. Edits
rewrite the poses of the edited rows only: the rotation that a row had learnt (``base @
exp(delta)``) is baked into ``base_rotations`` with a zero ``delta``, which renders identically.

Choices, documented here and in ``idsplat-edit --help``:

* ``move`` in the *instance* frame applies the offset after the pose, ``T' = T [Rz(yaw) | d]``:
  ``d = (0, 1, 0)`` is one metre to the vehicle's left at every time (a lane change) and the yaw
  turns it about its own vertical axis. In the *world* frame the whole path is turned by ``yaw``
  about its mean position and then shifted by ``d`` (world axes).
* ``retime(shift, speed)`` plays the instance's motion ``speed`` times as fast, starting ``shift``
  seconds later: ``T'(t) = T(t_a + speed (t - t_a - shift))`` with ``t_a`` its first step. All
  instances share one step grid (the training frames), so the new motion is resampled onto it;
  the presence span becomes the grid steps inside the new interval (plus the usual margin), and
  whatever falls outside the sequence is cut.
* ``duplicate`` copies an instance's Gaussians and trajectory under a new ID (one more than the
  largest ID in use), then moves the copy like ``move``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from idsplat_ns.model.so3 import so3_exp
from idsplat_ns.model.trajectories import InstanceTrajectories, default_span_margin

GAUSSIAN_KEYS = ("means", "scales", "quats", "opacities", "features_rgb", "features", "instance_ids")
TRAJECTORY_KEYS = ("positions", "rotation_deltas", "frame_times", "instance_ids", "span_first", "span_last", "base_rotations")
Frame = Literal["instance", "world"]


class EditError(ValueError):
    """An edit that cannot be applied (unknown ID, a speed <= 0, a shift out of the sequence)."""


def rot_z(yaw: float) -> Tensor:  # -> [3, 3] float64
    c, s = np.cos(yaw), np.sin(yaw)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


@dataclass
class SceneTensors:
    """The editable tensors of a scene model: Gaussians and (optionally) instance trajectories."""

    gaussians: dict[str, Tensor]  # GAUSSIAN_KEYS -> [N, ...]
    trajectories: dict[str, Tensor] | None  # TRAJECTORY_KEYS -> [Z, F, ...] / [F] / [Z]

    # -- state dict round trip -----------------------------------------------------------------

    @classmethod
    def from_state_dict(cls, state: dict[str, Tensor], prefix: str = "") -> "SceneTensors":
        """Read ``{prefix}gaussians.*`` and ``{prefix}trajectories.*`` (e.g. prefix
        ``_model.scene_model.`` in a nerfstudio checkpoint)."""
        missing = [k for k in GAUSSIAN_KEYS if f"{prefix}gaussians.{k}" not in state]
        if missing:
            raise EditError(f"not an IDSplat scene: no {prefix}gaussians.{missing[0]} in the checkpoint")
        g = {k: state[f"{prefix}gaussians.{k}"].detach().clone() for k in GAUSSIAN_KEYS}
        traj = None
        if f"{prefix}trajectories.positions" in state:
            traj = {k: state[f"{prefix}trajectories.{k}"].detach().clone() for k in TRAJECTORY_KEYS}
        return cls(g, traj)

    def to_state_dict(self, state: dict[str, Tensor], prefix: str = "") -> dict[str, Tensor]:
        """A copy of ``state`` with this scene's tensors in place (sizes may differ)."""
        out = dict(state)
        for k, v in self.gaussians.items():
            out[f"{prefix}gaussians.{k}"] = v
        if self.trajectories is not None:
            for k, v in self.trajectories.items():
                out[f"{prefix}trajectories.{k}"] = v
        return out

    # -- queries -------------------------------------------------------------------------------

    @property
    def instance_ids(self) -> list[int]:
        return [] if self.trajectories is None else [int(i) for i in self.trajectories["instance_ids"]]

    def row(self, instance_id: int) -> int:
        """Trajectory row of ``instance_id``; :class:`EditError` when it has none."""
        ids = self.instance_ids
        if instance_id not in ids:
            known = ", ".join(map(str, ids)) or "none"
            raise EditError(f"no instance {instance_id} in this scene (instances: {known})")
        return ids.index(instance_id)

    def as_trajectories(self, span_margin: float | None = None) -> InstanceTrajectories | None:
        """A live :class:`InstanceTrajectories` with these tensors (for posing at a time)."""
        if self.trajectories is None:
            return None
        t = self.trajectories
        Z, F = t["positions"].shape[:2]
        module = InstanceTrajectories.placeholder(Z, F, refine=False, dtype=t["positions"].dtype)
        module.positions = torch.nn.Parameter(t["positions"].clone(), requires_grad=False)
        module.rotation_deltas = torch.nn.Parameter(t["rotation_deltas"].clone(), requires_grad=False)
        for k in ("frame_times", "instance_ids", "span_first", "span_last", "base_rotations"):
            setattr(module, k, t[k].clone())
        module.span_margin = default_span_margin(t["frame_times"].double().numpy()) if span_margin is None else span_margin
        return module

    def step_rotations(self) -> Tensor:  # -> [Z, F, 3, 3] float64
        t = self.trajectories
        return t["base_rotations"].double() @ so3_exp(t["rotation_deltas"].double())

    def _set_row(self, z: int, positions: Tensor, rotations: Tensor) -> None:
        """Replace row ``z``'s poses ([F, 3], [F, 3, 3], float64); the learnt rotation is baked."""
        t = self.trajectories
        t["positions"][z] = positions.to(t["positions"].dtype)
        t["base_rotations"][z] = rotations.to(t["base_rotations"].dtype)
        t["rotation_deltas"][z] = 0.0

    def _span_steps(self, z: int) -> Tensor:  # -> [S] step indices of the valid span
        t = self.trajectories
        first, last = int(t["span_first"][z]), int(t["span_last"][z])
        return torch.arange(first, last + 1) if first >= 0 else torch.zeros(0, dtype=torch.int64)

    # -- edits ---------------------------------------------------------------------------------

    def remove(self, instance_ids: list[int]) -> None:
        """Drop the instances' Gaussians and trajectory rows."""
        for iid in instance_ids:
            self.row(iid)  # unknown IDs are an error, not a silent no-op
        drop = torch.tensor(instance_ids, dtype=torch.int64)
        keep_g = ~torch.isin(self.gaussians["instance_ids"], drop)
        self.gaussians = {k: v[keep_g] for k, v in self.gaussians.items()}
        t = self.trajectories
        keep_z = ~torch.isin(t["instance_ids"], drop)
        for k in ("positions", "rotation_deltas", "instance_ids", "span_first", "span_last", "base_rotations"):
            t[k] = t[k][keep_z]

    def move(self, instance_id: int, offset: tuple[float, float, float], yaw: float = 0.0, frame: Frame = "instance") -> None:
        """Shift (metres) and turn (radians about z) an instance at every time; see the module doc."""
        z = self.row(instance_id)
        p = self.trajectories["positions"][z].double()  # [F, 3]
        R = self.step_rotations()[z]  # [F, 3, 3]
        d = torch.tensor(offset, dtype=torch.float64)
        Rz = rot_z(yaw)
        if frame == "instance":
            new_p, new_R = p + (R @ d), R @ Rz
        elif frame == "world":
            steps = self._span_steps(z)
            centre = p[steps].mean(0) if len(steps) else p.mean(0)
            new_p, new_R = (p - centre) @ Rz.T + centre + d, Rz @ R
        else:
            raise EditError(f"frame must be 'instance' or 'world', not {frame!r}")
        self._set_row(z, new_p, new_R)

    def retime(self, instance_id: int, shift: float, speed: float = 1.0) -> None:
        """Start the instance ``shift`` seconds later and play its motion ``speed`` times as fast."""
        if not speed > 0:
            raise EditError(f"retime {instance_id}: the speed factor must be > 0, not {speed}")
        z = self.row(instance_id)
        t = self.trajectories
        times = t["frame_times"].double()  # [F]
        first, last = int(t["span_first"][z]), int(t["span_last"][z])
        if first < 0:
            raise EditError(f"retime {instance_id}: the instance has no valid step to re-time")
        t_a, t_b = float(times[first]), float(times[last])
        start, end = t_a + shift, t_a + shift + (t_b - t_a) / speed
        eps = 1e-6 * max(1.0, abs(t_b))
        inside = torch.nonzero((times >= start - eps) & (times <= end + eps)).squeeze(-1)
        if len(inside) == 0:
            raise EditError(f"retime {instance_id}: shifted by {shift} s at speed x{speed} it is at no step of the "
                            f"sequence ({float(times[0]):.2f} to {float(times[-1]):.2f} s); use a smaller shift")
        module = self.as_trajectories(span_margin=0.0)
        new_p = torch.empty(len(times), 3, dtype=torch.float64)  # [F, 3]
        new_R = torch.empty(len(times), 3, 3, dtype=torch.float64)  # [F, 3, 3]
        # The old time shown at each step; steps outside the new span hold the end poses.
        source = (t_a + speed * (times - t_a - shift)).clamp(t_a, t_b)  # [F]
        with torch.no_grad():
            for k in range(len(times)):
                R, p, _ = module.poses_at(float(source[k]))
                new_R[k], new_p[k] = R[z].double(), p[z].double()
        self._set_row(z, new_p, new_R)
        t["span_first"][z], t["span_last"][z] = int(inside[0]), int(inside[-1])

    def duplicate(self, instance_id: int, offset: tuple[float, float, float], yaw: float = 0.0,
                  frame: Frame = "instance") -> int:
        """Copy an instance under a new ID and move the copy; returns the new ID."""
        z = self.row(instance_id)
        gids = self.gaussians["instance_ids"]
        new_id = max(self.instance_ids + [int(gids.max()) if gids.numel() else 0]) + 1
        mine = self.gaussians["instance_ids"] == instance_id
        for k, v in self.gaussians.items():
            copy = v[mine].clone()
            if k == "instance_ids":
                copy.fill_(new_id)
            self.gaussians[k] = torch.cat([v, copy])
        t = self.trajectories
        for k in ("positions", "rotation_deltas", "span_first", "span_last", "base_rotations"):
            t[k] = torch.cat([t[k], t[k][z : z + 1].clone()])
        t["instance_ids"] = torch.cat([t["instance_ids"], torch.tensor([new_id], dtype=t["instance_ids"].dtype)])
        self.move(new_id, offset, yaw, frame)
        return new_id
