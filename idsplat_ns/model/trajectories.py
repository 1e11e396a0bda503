"""Learnable instance trajectories: a rigid pose per instance and time step, interpolated in time.

The paper (Sec. 3.5, supplementary Table 10) optimises, per instance ``z`` and time step ``k``, a
position and a rotation, initialised from the smoothed trajectory, jointly with the Gaussians
(positions: lr 1e-3 -> 1e-4, rotations: 5e-5 -> 1e-6, both with 1500 warm-up steps). Poses at a
render time between steps come from interpolating the bracketing steps.

Parametrisation (why): positions are learned directly in world metres; rotations are the initial
rotation times a small body-frame correction ``R = R0 @ exp(delta)``, ``delta`` zero-initialised,
so that the optimiser's learning rate reads as radians and Adam's step is isotropic in rotation.

Interpolation and presence (the choices, documented here and tested):

* An instance's *span* runs from its first to its last valid step. Invalid steps inside the span
  (gaps, e.g. frames where the oracle box or a registration is missing) are initialised by
  interpolating their valid neighbours and are then ordinary learnable steps: images at those
  times still supervise the object.
* At a time ``t`` inside the span the pose interpolates the two bracketing steps: translation
  linearly, rotation along the geodesic ``R_k exp(w log(R_k^T R_k+1))`` (slerp), with
  ``w = (t - t_k) / (t_k+1 - t_k)``; at a step time it equals that step exactly.
* An instance is *present* at ``t`` iff ``t`` lies in ``[t_first - margin, t_last + margin]``.
  The margin (default: half the median step) exists because a frame's sensors do not fire at the
  frame's own time: a camera may expose a few ms before the lidar sweep time that defines the
  frame, and lidar rays span a whole sweep; with a zero margin an object would vanish from the
  very images that observed it at the ends of its span. Inside the margin the end segment is
  extrapolated at constant velocity (the same formula with ``w`` outside [0, 1]); an instance
  with a single valid step keeps that pose. Set ``span_margin=0`` for the strict span.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from idsplat_ns.data.geometry import interpolate_poses
from idsplat_ns.instances.tracks import InstanceTracks
from idsplat_ns.model.so3 import so3_exp, so3_log


@dataclass(frozen=True)
class TrajectoryLearningRates:
    """The paper's optimiser settings for trajectories (supplementary Table 10); exponential decay."""

    positions_initial: float = 1e-3
    """Initial learning rate of the per-step positions (metres)."""
    positions_final: float = 1e-4
    """Final learning rate of the positions."""
    rotations_initial: float = 5e-5
    """Initial learning rate of the per-step so(3) corrections (radians)."""
    rotations_final: float = 1e-6
    """Final learning rate of the rotation corrections."""
    warmup_steps: int = 1500
    """Warm-up steps of both groups."""


# ---------------------------------------------------------------------------------------------
# The module
# ---------------------------------------------------------------------------------------------


def _fill_gaps(times: np.ndarray, poses: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Poses [F, 4, 4] with invalid steps interpolated from valid ones (ends: nearest valid),
    plus the first and last valid step (-1, -1 when none is valid)."""
    good = np.flatnonzero(valid)
    if len(good) == 0:
        return np.repeat(np.eye(4)[None], len(times), 0), -1, -1
    filled = interpolate_poses(times[good], poses[good], times)  # clamps outside [first, last]
    filled[good] = poses[good]
    return filled, int(good[0]), int(good[-1])


def default_span_margin(frame_times: np.ndarray) -> float:  # frame_times: [F] seconds
    """Half the median step: how far past its first and last step an instance stays present."""
    return 0.5 * float(np.median(np.diff(frame_times))) if len(frame_times) > 1 else 0.0


class InstanceTrajectories(nn.Module):
    """Per-instance, per-step rigid poses (canonical -> world), learnable, interpolated in time."""

    def __init__(
        self,
        frame_times: np.ndarray,  # [F] float64 seconds, increasing
        instance_ids: np.ndarray,  # [Z] int >= 1
        poses: np.ndarray,  # [Z, F, 4, 4] canonical -> world
        valid: np.ndarray,  # [Z, F] bool
        refine: bool = True,
        span_margin: float | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        """``refine=False`` freezes the poses (the paper's ablation g). ``span_margin`` (seconds)
        widens each instance's presence span at both ends (default: half the median step)."""
        super().__init__()
        frame_times = np.asarray(frame_times, dtype=np.float64)
        ids = np.asarray(instance_ids, dtype=np.int64).reshape(-1)
        poses = np.asarray(poses, dtype=np.float64)
        valid = np.asarray(valid, dtype=bool)
        F, Z = len(frame_times), len(ids)
        if F == 0:
            raise ValueError("InstanceTrajectories: needs at least one time step")
        if np.any(np.diff(frame_times) <= 0):
            raise ValueError("InstanceTrajectories: frame_times must be strictly increasing")
        if poses.shape != (Z, F, 4, 4) or valid.shape != (Z, F):
            raise ValueError(f"InstanceTrajectories: poses {poses.shape} / valid {valid.shape} do not match Z={Z}, F={F}")
        if np.any(ids < 1) or len(np.unique(ids)) != Z:
            raise ValueError("InstanceTrajectories: instance ids must be unique and >= 1 (0 is the background)")
        if span_margin is None:
            span_margin = default_span_margin(frame_times)
        filled = np.empty((Z, F, 4, 4))
        first = np.full(Z, -1, dtype=np.int64)
        last = np.full(Z, -1, dtype=np.int64)
        for z in range(Z):
            filled[z], first[z], last[z] = _fill_gaps(frame_times, poses[z], valid[z])

        self.refine = refine
        self.span_margin = float(span_margin)
        self.register_buffer("frame_times", torch.from_numpy(frame_times))  # float64: seconds
        self.register_buffer("instance_ids", torch.from_numpy(ids))
        self.register_buffer("span_first", torch.from_numpy(first))  # [Z] first valid step (-1: none)
        self.register_buffer("span_last", torch.from_numpy(last))  # [Z] last valid step
        self.register_buffer("base_rotations", torch.from_numpy(filled[..., :3, :3]).to(dtype))  # [Z, F, 3, 3]
        self.positions = nn.Parameter(torch.from_numpy(filled[..., :3, 3]).to(dtype), requires_grad=refine)
        self.rotation_deltas = nn.Parameter(torch.zeros(Z, F, 3, dtype=dtype), requires_grad=refine)

    @classmethod
    def from_instance_tracks(
        cls, tracks: InstanceTracks, refine: bool = True, span_margin: float | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> InstanceTrajectories:
        """Trajectories of the dynamic instances of ``tracks`` (static instances stay background)."""
        insts = tracks.instances
        F = len(tracks.frame_times)
        poses = np.stack([i.poses for i in insts]) if insts else np.zeros((0, F, 4, 4))
        valid = np.stack([i.valid for i in insts]) if insts else np.zeros((0, F), bool)
        ids = np.array([i.instance_id for i in insts], dtype=np.int64)
        return cls(tracks.frame_times, ids, poses, valid, refine=refine, span_margin=span_margin, dtype=dtype)

    @classmethod
    def placeholder(cls, num_instances: int, num_steps: int, refine: bool = True,
                    dtype: torch.dtype = torch.float32) -> InstanceTrajectories:
        """Trajectories of the given sizes whose values a checkpoint's state dict replaces (ns-eval
        and the viewer: a checkpoint, not today's preprocessing, says what the instances are).
        Call :meth:`reset_span_margin` after loading."""
        F = max(num_steps, 1)
        return cls(np.arange(F, dtype=np.float64), np.arange(1, num_instances + 1),
                   np.tile(np.eye(4), (num_instances, F, 1, 1)), np.ones((num_instances, F), bool),
                   refine=refine, dtype=dtype)

    def reset_span_margin(self) -> None:
        """The default presence margin (half the median step) for the current ``frame_times``."""
        self.span_margin = default_span_margin(self.frame_times.detach().cpu().double().numpy())

    # -- sizes and parameter groups ----------------------------------------------------------

    @property
    def num_instances(self) -> int:
        return int(self.instance_ids.shape[0])

    @property
    def num_steps(self) -> int:
        return int(self.frame_times.shape[0])

    def position_parameters(self) -> list[nn.Parameter]:
        """The positions group (empty when ``refine`` is off)."""
        return [self.positions] if self.refine else []

    def rotation_parameters(self) -> list[nn.Parameter]:
        """The rotation-correction group (empty when ``refine`` is off)."""
        return [self.rotation_deltas] if self.refine else []

    def step_rotations(self) -> Tensor:  # -> [Z, F, 3, 3]
        """Current rotations of every step: ``R0 @ exp(delta)``."""
        return self.base_rotations @ so3_exp(self.rotation_deltas)

    def step_poses(self) -> Tensor:  # -> [Z, F, 4, 4]
        """Current canonical-to-world poses of every step (for tracking evaluation and export)."""
        Z, F = self.num_instances, self.num_steps
        out = torch.zeros(Z, F, 4, 4, dtype=self.positions.dtype, device=self.positions.device)
        out[..., :3, :3] = self.step_rotations()
        out[..., :3, 3] = self.positions
        out[..., 3, 3] = 1.0
        return out

    # -- queries at a time -------------------------------------------------------------------

    @torch.no_grad()
    def positions_at(self, t: float) -> dict[int, np.ndarray]:
        """``{instance_id: canonical-frame origin in the world [3]}`` of the instances present at t."""
        _, trans, present = self.poses_at(t)
        ids = self.instance_ids.tolist()
        return {int(ids[k]): trans[k].double().cpu().numpy() for k in range(len(ids)) if bool(present[k])}

    def present_at(self, t: float | Tensor) -> Tensor:  # -> [Z] bool, or [K, Z] for times [K]
        """Which instances exist at time ``t`` (seconds; a float, a scalar tensor, or a tensor of K
        times): inside their valid span (+ margin). Compared on the device: no host read of ``t``."""
        tv = t.detach().to(self.frame_times.dtype) if isinstance(t, Tensor) else float(t)
        if isinstance(tv, Tensor) and tv.dim() == 1:
            tv = tv[:, None]
        has = self.span_first >= 0
        first = self.frame_times[self.span_first.clamp_min(0)]
        last = self.frame_times[self.span_last.clamp_min(0)]
        return has & (tv >= first - self.span_margin) & (tv <= last + self.span_margin)

    def ids_present_at(self, t: float | Tensor) -> Tensor:  # -> [Z'] int64
        """Instance IDs present at time ``t``."""
        return self.instance_ids[self.present_at(t)]

    def poses_at(self, t: float | Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Poses of all instances at time ``t`` (seconds; a float or a scalar tensor).

        Returns ``R`` [Z, 3, 3], ``trans`` [Z, 3] (canonical -> world) and ``present`` [Z] bool.
        Differentiable w.r.t. the trajectory parameters and, when ``t`` is a tensor that requires
        grad (a learnable camera time offset), w.r.t. ``t``. Poses of absent instances are the
        extrapolated/clamped values and must not be used.
        """
        R, trans, present, _, _ = self._interpolate(t, velocities=False)
        return R, trans, present

    def poses_at_times(self, times: Tensor) -> tuple[Tensor, Tensor, Tensor]:  # times: [K] seconds
        """:meth:`poses_at` at K times in one batch of operations (a lidar batch's time bins):
        ``R`` [K, Z, 3, 3], ``trans`` [K, Z, 3], ``present`` [K, Z] bool, each row ``k`` equal to
        ``poses_at(times[k])``."""
        if times.dim() != 1:
            raise ValueError(f"poses_at_times: times must be one-dimensional [K], got shape {tuple(times.shape)}")
        R, trans, present, _, _ = self._interpolate(times, velocities=False)
        return R, trans, present

    def motion_at(self, t: float | Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """:meth:`poses_at` plus the instances' world-frame velocities at ``t``: ``(R, trans,
        present, linear [Z, 3] m/s, angular [Z, 3] rad/s)``. A point ``x`` of instance z moves at
        ``linear[z] + angular[z] x (x - trans[z])``. The velocities are those of the segment that
        brackets ``t`` (constant along it), zero for an instance with a single valid step."""
        return self._interpolate(t, velocities=True)

    def _interpolate(self, t: float | Tensor, velocities: bool) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """Poses (and velocities) at ``t``: a float or scalar tensor ([Z, ...] outputs), or a tensor
        of K times ([K, Z, ...] outputs, one batch of operations for all of them)."""
        batched = isinstance(t, Tensor) and t.dim() == 1
        present = self.present_at(t)
        Z = self.num_instances
        dtype, device = self.positions.dtype, self.positions.device
        tdt = self.frame_times.dtype  # float64 unless the module was cast
        t_k = (t.reshape(-1).to(device=device, dtype=tdt) if isinstance(t, Tensor)
               else torch.tensor([float(t)], dtype=tdt, device=device))  # [K]
        K = t_k.shape[0]
        if Z == 0:
            empty = torch.zeros(K, 0, 3, dtype=dtype, device=device)
            R, trans = torch.zeros(K, 0, 3, 3, dtype=dtype, device=device), empty
            return (R, trans, present, empty, empty) if batched else (R[0], trans[0], present, empty[0], empty[0])
        first = self.span_first.clamp_min(0)
        last = self.span_last.clamp_min(0)
        # Left step of the bracketing segment, restricted to the instance's span: [K, Z].
        k_global = torch.searchsorted(self.frame_times, t_k.detach(), right=True) - 1
        k0 = torch.minimum(k_global[:, None], (last - 1).clamp_min(0)[None])
        k0 = torch.maximum(k0, first[None])
        k1 = torch.minimum(k0 + 1, last[None])
        t0, t1 = self.frame_times[k0], self.frame_times[k1]
        single = k1 == k0  # one valid step: constant pose
        dt = torch.where(single, torch.ones_like(t0), t1 - t0)
        w = torch.where(single, torch.zeros_like(t0), (t_k[:, None] - t0) / dt).to(dtype)  # [K, Z]

        # Rows (z, k) of the [Z, F, ...] tables by index_select of the flattened table: its backward
        # is an index_add, advanced indexing's a sort (a kernel chain per call on CUDA).
        steps = self.positions.shape[1]
        zi = torch.arange(Z, device=device) * steps
        r0, r1 = (zi + k0).reshape(-1), (zi + k1).reshape(-1)  # [K Z]
        positions = self.positions.flatten(0, 1)
        p0, p1 = positions.index_select(0, r0).view(K, Z, 3), positions.index_select(0, r1).view(K, Z, 3)
        trans = p0 + w[..., None] * (p1 - p0)
        base, deltas = self.base_rotations.flatten(0, 1), self.rotation_deltas.flatten(0, 1)
        # Both ends of every segment through one exponential map.
        ends = base.index_select(0, torch.cat([r0, r1])) @ so3_exp(deltas.index_select(0, torch.cat([r0, r1])))
        R0, R1 = ends.view(2, K, Z, 3, 3).unbind(0)
        rel = so3_log(R0.transpose(-1, -2) @ R1)  # [K, Z, 3] geodesic from step k0 to k1
        R = R0 @ so3_exp(w[..., None] * rel)
        if not velocities:
            linear = angular = trans
        else:
            # d/dt of R0 exp(w rel) is R [rel / dt]x: body rate rel / dt, world rate R rel / dt.
            inv_dt = torch.where(single, torch.zeros_like(dt), 1.0 / dt).to(dtype)[..., None]
            linear = (p1 - p0) * inv_dt
            angular = (R @ (rel * inv_dt)[..., None]).squeeze(-1)
        if batched:
            return R, trans, present, linear, angular
        return R[0], trans[0], present, linear[0], angular[0]

    def forward(self, t: float | Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Same as :meth:`poses_at`."""
        return self.poses_at(t)

    def pose_matrices_at(self, t: float | Tensor) -> tuple[Tensor, Tensor]:
        """``(T [Z, 4, 4], present [Z])``: the poses of :meth:`poses_at` as homogeneous matrices."""
        R, trans, present = self.poses_at(t)
        T = torch.zeros(R.shape[0], 4, 4, dtype=R.dtype, device=R.device)
        T[:, :3, :3] = R
        T[:, :3, 3] = trans
        T[:, 3, 3] = 1.0
        return T, present
