"""Compose the scene at a time: static Gaussians as they are, instance Gaussians moved to the world.

Paper Eq. (1): ``mu_{i,t} = T_{z_i,t} mu_i``; a Gaussian's orientation turns with its instance,
so its quaternion becomes ``q(R) * q``. Gaussians of instances that do not exist at the render
time (outside their trajectory span) are dropped, as are IDs that have no trajectory.

All functions are differentiable w.r.t. means, quaternions and the poses, and work on whichever
device and float dtype their inputs use.
"""

from __future__ import annotations

import torch
from torch import Tensor

from idsplat_ns.model.so3 import constant, rotmat_to_quat

# The left-multiplication matrix L(a) of a = (w, x, y, z), with a * b = L(a) b, flattened
# row-major, as a linear map of a: row i of _LEFT holds the signs with which a's component i
# enters the 16 entries ([w -x -y -z; x w -z y; y z w -x; z -y x w]).
_LEFT = (
    (1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1),
    (0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 0, -1, 0, 0, 1, 0),
    (0, 0, -1, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, -1, 0, 0),
    (0, 0, 0, -1, 0, 0, -1, 0, 0, 1, 0, 0, 1, 0, 0, 0),
)


def quat_multiply(a: Tensor, b: Tensor) -> Tensor:  # a, b: [..., 4] wxyz -> [..., 4]
    """Hamilton product ``a * b`` (the rotation of ``b`` followed by that of ``a``); norms multiply.
    One linear map and one product: a handful of operators for any batch (the step is bound by
    launching them)."""
    left = (a @ constant(_LEFT, a.dtype, a.device)).unflatten(-1, (4, 4))  # [..., 4, 4]
    return (left @ b[..., None]).squeeze(-1)


def quat_conjugate(q: Tensor) -> Tensor:  # q: [..., 4] -> [..., 4]
    """``(w, -x, -y, -z)``: the inverse rotation for a unit quaternion."""
    return q * constant((1.0, -1.0, -1.0, -1.0), q.dtype, q.device)


def canonical_to_world(points: Tensor, R: Tensor, t: Tensor) -> Tensor:
    """``R p + t`` for points [..., 3] with rotations [..., 3, 3] and translations [..., 3]
    (broadcast: one pose for all points, or one pose per point)."""
    return (R @ points[..., None]).squeeze(-1) + t


def world_to_canonical(points_world: Tensor, R: Tensor, t: Tensor) -> Tensor:
    """Inverse of :func:`canonical_to_world`: ``R^T (p - t)``; same broadcasting."""
    return (R.transpose(-1, -2) @ (points_world - t)[..., None]).squeeze(-1)


def rotate_quats(R: Tensor, quats: Tensor) -> Tensor:
    """Orientations [..., 4] (wxyz, any norm) turned by rotations [..., 3, 3]: ``q(R) * q``."""
    return quat_multiply(rotmat_to_quat(R), quats)


def unrotate_quats(R: Tensor, quats_world: Tensor) -> Tensor:
    """Inverse of :func:`rotate_quats`: ``q(R)^-1 * q`` (world orientation -> canonical)."""
    return quat_multiply(quat_conjugate(rotmat_to_quat(R)), quats_world)


def trajectory_index(instance_ids: Tensor, traj_ids: Tensor) -> Tensor:
    """Row of each Gaussian's instance in the trajectory arrays: [N] int64, -1 for the background
    (ID 0) and for IDs without a trajectory. A search in the sorted IDs: no host read of a size."""
    ids = instance_ids.long()
    traj_ids = traj_ids.long().to(ids.device)
    if traj_ids.numel() == 0:
        return torch.full_like(ids, -1)
    sorted_ids, order = torch.sort(traj_ids)
    pos = torch.searchsorted(sorted_ids, ids).clamp_max(traj_ids.numel() - 1)
    found = (sorted_ids.index_select(0, pos) == ids) & (ids > 0)  # ID 0 is the background, never an instance
    return torch.where(found, order.index_select(0, pos), torch.full_like(ids, -1))


def compose_gaussians(
    means: Tensor,  # [N, 3] world (ID 0) or canonical (ID k > 0)
    quats: Tensor,  # [N, 4] wxyz, any norm (the norm is kept)
    instance_ids: Tensor,  # [N] int
    traj_R: Tensor,  # [Z, 3, 3] canonical -> world rotation of each trajectory at the render time
    traj_t: Tensor,  # [Z, 3] translation
    present: Tensor,  # [Z] bool, instance exists at the render time
    traj_ids: Tensor,  # [Z] int instance ID of each trajectory row
    drop: bool = True,
) -> tuple[Tensor, Tensor, Tensor]:
    """World means [M, 3] and quaternions [M, 4] of the Gaussians to render, and ``keep`` [N] bool.

    Rows of the outputs are the kept Gaussians in their original order (``means[keep]`` order),
    so other per-Gaussian tensors are selected with the same ``keep``. Static Gaussians pass
    unchanged; instance Gaussians are moved by their instance's pose; Gaussians of absent
    instances, or with an ID that has no trajectory, are dropped. ``drop=False`` keeps every row
    (M = N; the ones ``keep`` marks False hold finite placeholder poses): for a caller that
    hides them by their opacity instead of gathering every per-Gaussian tensor.
    """
    n = means.shape[0]
    # Only the instance Gaussians (a few percent of a street) are indexed: no [N]-row gathers
    # unless something is dropped, which is what posing a lidar batch bin by bin costs.
    dyn = torch.nonzero(instance_ids > 0).squeeze(-1)  # [M]
    keep = torch.ones(n, dtype=torch.bool, device=means.device)
    if dyn.numel() == 0:
        return means, quats, keep
    row = trajectory_index(instance_ids.index_select(0, dyn), traj_ids)  # [M], -1: no trajectory
    # Row -1 (an ID without a trajectory) reads the appended False: safe also when Z == 0.
    present_pad = torch.cat([present.to(device=means.device, dtype=torch.bool),
                             torch.zeros(1, dtype=torch.bool, device=means.device)])
    here = present_pad[row]  # [M]
    if traj_R.shape[0] == 0:  # no trajectory at all: nothing to move, every instance row is dropped
        means_w, quats_w = means, quats
    else:
        r = row.clamp_min(0)  # absent or unknown rows are posed with row 0's pose, then dropped
        # One pose per instance Gaussian (only those, not all N). index_select, not traj_R[r]: the
        # backward of advanced indexing sorts M indices that hold only Z values, which CUDA then
        # accumulates one after another (about 3 ms a call at 63,000 instance Gaussians on an H200).
        R, t = traj_R.index_select(0, r), traj_t.index_select(0, r)
        moved_means = canonical_to_world(means.index_select(0, dyn), R, t)
        # q(R) once per trajectory, then gathered: cheaper than converting N matrices.
        moved_quats = quat_multiply(rotmat_to_quat(traj_R).index_select(0, r), quats.index_select(0, dyn))
        means_w = means.index_put((dyn,), moved_means)
        quats_w = quats.index_put((dyn,), moved_quats)
    if bool(here.all()):
        return means_w, quats_w, keep
    keep[dyn] = here
    if drop:  # index_select: see SceneModel.posed_gaussians
        rows = torch.nonzero(keep).squeeze(1)
        means_w, quats_w = means_w.index_select(0, rows), quats_w.index_select(0, rows)
    return means_w, quats_w, keep


def gaussian_velocities(
    means_world: Tensor,  # [M, 3] composed means (the output of compose_gaussians)
    instance_ids: Tensor,  # [M] int, their instance IDs
    traj_t: Tensor,  # [Z, 3] translation of each trajectory at the render time
    traj_linear: Tensor,  # [Z, 3] world-frame linear velocity (m/s)
    traj_angular: Tensor,  # [Z, 3] world-frame angular velocity (rad/s)
    traj_ids: Tensor,  # [Z] int instance ID of each trajectory row
) -> Tensor:  # [M, 3]
    """World-frame velocity of each composed Gaussian mean: zero for the background, the rigid
    motion ``v + w x (x - t)`` of its instance otherwise (what the rolling shutter needs)."""
    row = trajectory_index(instance_ids, traj_ids)
    dyn = torch.nonzero(row >= 0).squeeze(-1)
    out = torch.zeros_like(means_world)
    if dyn.numel() == 0:
        return out
    r = row[dyn]
    moving = traj_linear[r] + torch.cross(traj_angular[r], means_world[dyn] - traj_t[r], dim=-1)
    return out.index_put((dyn,), moving)


def compose_gaussians_at_times(
    means: Tensor,  # [N, 3], or [K, N, 3] per time (a deformation), world (ID 0) or canonical (ID k > 0)
    quats: Tensor,  # [N, 4] wxyz, any norm
    instance_ids: Tensor,  # [N] int
    traj_R: Tensor,  # [K, Z, 3, 3] canonical -> world rotation of each trajectory at each of K times
    traj_t: Tensor,  # [K, Z, 3]
    present: Tensor,  # [K, Z] bool
    traj_ids: Tensor,  # [Z] int
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`compose_gaussians` with ``drop=False`` at K times in one batch of operations: world
    means [K, N, 3], quaternions [K, N, 4] and ``keep`` [K, N] bool, row ``k`` equal to the
    single-time composition at time ``k``. Every Gaussian keeps its row; absent ones hold finite
    placeholder poses and ``keep`` False."""
    k, n = traj_R.shape[0], instance_ids.shape[0]
    means_k = means.expand(k, n, 3)
    quats_k = quats.expand(k, n, 4)
    keep = torch.ones(k, n, dtype=torch.bool, device=means.device)
    dyn = torch.nonzero(instance_ids > 0).squeeze(-1)  # [M]
    if dyn.numel() == 0:
        return means_k, quats_k, keep
    row = trajectory_index(instance_ids.index_select(0, dyn), traj_ids)  # [M], -1: no trajectory
    z = traj_R.shape[1]
    # Row -1 reads an appended False column: safe also when Z == 0.
    present_pad = torch.cat([present.to(device=means.device, dtype=torch.bool),
                             torch.zeros(k, 1, dtype=torch.bool, device=means.device)], dim=1)  # [K, Z + 1]
    here = present_pad.index_select(1, torch.where(row < 0, z, row))  # [K, M]
    keep = keep.index_copy(1, dyn, here)
    if z == 0:
        return means_k, quats_k, keep
    r = row.clamp_min(0)  # absent or unknown rows take row 0's pose and are marked in ``keep``
    R, t = traj_R.index_select(1, r), traj_t.index_select(1, r)  # [K, M, 3, 3], [K, M, 3]
    moved_means = canonical_to_world(means_k.index_select(1, dyn), R, t)
    moved_quats = quat_multiply(rotmat_to_quat(traj_R).index_select(1, r), quats.index_select(0, dyn)[None])
    # index_copy: the static rows are copied once per time, the instance rows replaced; its backward
    # is an index_fill and an index_select (no sort of indices).
    return means_k.index_copy(1, dyn, moved_means), quats_k.index_copy(1, dyn, moved_quats), keep
