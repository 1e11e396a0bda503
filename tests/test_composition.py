"""Composing static and instance Gaussians at a render time: transforms, gradients, dropping."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from idsplat_ns.data.geometry import quat_to_rotmat, rot_z
from idsplat_ns.model.composition import (
    canonical_to_world,
    compose_gaussians,
    quat_multiply,
    rotate_quats,
    unrotate_quats,
    world_to_canonical,
)
from idsplat_ns.model.so3 import so3_exp
from idsplat_ns.model.trajectories import InstanceTrajectories

D = torch.float64


def _scene(seed: int = 0, n: int = 9):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=D)
    quats = torch.randn(n, 4, generator=g, dtype=D)
    ids = torch.tensor([0, 1, 1, 4, 0, 4, 9, 1, 4][:n])  # 9 has no trajectory
    traj_ids = torch.tensor([4, 1, 6])  # trajectory rows in arbitrary order; 6 has no Gaussians
    traj_R = so3_exp(torch.randn(3, 3, generator=g, dtype=D))
    traj_t = torch.randn(3, 3, generator=g, dtype=D) * 5
    return means, quats, ids, traj_R, traj_t, traj_ids


def test_quat_multiply_matches_scipy():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(20, 4)), rng.normal(size=(20, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    ours = quat_multiply(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    ref = (Rotation.from_quat(a[:, [1, 2, 3, 0]]) * Rotation.from_quat(b[:, [1, 2, 3, 0]])).as_quat()[:, [3, 0, 1, 2]]
    sign = np.sign(np.sum(ours * ref, axis=1, keepdims=True))  # q and -q are the same rotation
    assert np.allclose(ours, sign * ref, atol=1e-12)


def test_compose_moves_instances_keeps_static_and_drops_absent():
    means, quats, ids, R, t, traj_ids = _scene()
    present = torch.tensor([True, True, True])
    mw, qw, keep = compose_gaussians(means, quats, ids, R, t, present, traj_ids)
    assert keep.tolist() == [True, True, True, True, True, True, False, True, True]  # ID 9: no trajectory
    assert mw.shape == (8, 3) and qw.shape == (8, 4)
    kept = torch.nonzero(keep).squeeze(1).tolist()
    row = {4: 0, 1: 1}
    for out_i, i in enumerate(kept):
        z = int(ids[i])
        if z == 0:
            assert torch.equal(mw[out_i], means[i]) and torch.equal(qw[out_i], quats[i])
            continue
        Rz, tz = R[row[z]].numpy(), t[row[z]].numpy()
        assert np.allclose(mw[out_i].numpy(), Rz @ means[i].numpy() + tz, atol=1e-12)
        # Independent reference: the composed orientation is R times the Gaussian's rotation.
        assert np.allclose(quat_to_rotmat(qw[out_i].numpy()), Rz @ quat_to_rotmat(quats[i].numpy()), atol=1e-12)
        assert np.isclose(qw[out_i].norm().item(), quats[i].norm().item())  # the norm is kept

    # Instance 4 absent: its Gaussians are dropped, the others unchanged.
    mw2, _, keep2 = compose_gaussians(means, quats, ids, R, t, torch.tensor([False, True, True]), traj_ids)
    assert keep2.tolist() == [True, True, True, False, True, False, False, True, False]
    assert torch.equal(mw2, mw[[0, 1, 2, 4, 6]])


def test_compose_without_dropping_keeps_every_row_and_marks_the_absent():
    means, quats, ids, R, t, traj_ids = _scene()
    for present in ([True, True, True], [False, True, True], [False, False, False]):
        present = torch.tensor(present)
        mw, qw, keep = compose_gaussians(means, quats, ids, R, t, present, traj_ids)
        all_w, all_q, all_keep = compose_gaussians(means, quats, ids, R, t, present, traj_ids, drop=False)
        assert all_w.shape == means.shape and all_q.shape == quats.shape
        assert torch.equal(all_keep, keep)
        assert torch.equal(all_w[keep], mw) and torch.equal(all_q[keep], qw)
        assert torch.isfinite(all_w).all() and torch.isfinite(all_q).all()
    # Without any trajectory every instance row is marked, none moved.
    all_w, _, all_keep = compose_gaussians(means, quats, ids, R[:0], t[:0], present[:0], traj_ids[:0], drop=False)
    assert all_keep.tolist() == (ids == 0).tolist() and torch.equal(all_w, means)


def test_compose_without_instances_is_identity():
    means, quats, _, _, _, _ = _scene()
    ids = torch.zeros(9, dtype=torch.int64)
    empty = torch.zeros(0, dtype=torch.int64)
    mw, qw, keep = compose_gaussians(means, quats, ids, torch.zeros(0, 3, 3, dtype=D), torch.zeros(0, 3, dtype=D),
                                     torch.zeros(0, dtype=torch.bool), empty)
    assert keep.all() and torch.equal(mw, means) and torch.equal(qw, quats)


def test_canonical_world_round_trip():
    g = torch.Generator().manual_seed(3)
    p = torch.randn(50, 3, generator=g, dtype=D)
    q = torch.randn(50, 4, generator=g, dtype=D)
    R = so3_exp(torch.randn(50, 3, generator=g, dtype=D))  # one pose per point
    t = torch.randn(50, 3, generator=g, dtype=D)
    w = canonical_to_world(p, R, t)
    assert torch.allclose(world_to_canonical(w, R, t), p, atol=1e-12)
    assert torch.allclose(unrotate_quats(R, rotate_quats(R, q)), q, atol=1e-12)
    R1, t1 = R[0], t[0]  # one pose for all points (broadcast)
    assert torch.allclose(world_to_canonical(canonical_to_world(p, R1, t1), R1, t1), p, atol=1e-12)
    assert torch.allclose(canonical_to_world(p, R1, t1), p @ R1.T + t1, atol=1e-12)


def test_gradcheck_compose_wrt_means_quats_and_poses():
    means, quats, ids, R, t, traj_ids = _scene(n=9)
    present = torch.tensor([True, True, False])
    inputs = tuple(x.clone().requires_grad_(True) for x in (means, quats, R, t))

    def f(m, q, RR, tt):
        mw, qw, _ = compose_gaussians(m, q, ids, RR, tt, present, traj_ids)
        return mw, qw

    assert torch.autograd.gradcheck(f, inputs)


def test_gradcheck_compose_wrt_trajectory_parameters():
    """End to end: composed world means and quaternions w.r.t. the learnable trajectory steps."""
    times = np.array([0.0, 0.1, 0.2])
    poses = np.repeat(np.eye(4)[None, None], 2, 0).repeat(3, 1)
    poses[0, :, :3, :3] = rot_z(np.array([0.0, 0.3, 0.5]))
    poses[0, :, :3, 3] = [[0, 0, 0], [1, 0, 0], [2, 0.5, 0]]
    poses[1, :, :3, 3] = [[5, 5, 0], [5, 6, 0], [5, 7, 0]]
    traj = InstanceTrajectories(times, np.array([1, 2]), poses, np.ones((2, 3), bool), dtype=D)
    means, quats, _, _, _, _ = _scene(n=6)
    ids = torch.tensor([0, 1, 1, 2, 2, 1])
    pos = traj.positions.detach().clone().requires_grad_(True)
    rot = (0.01 * torch.randn(2, 3, 3, dtype=D, generator=torch.Generator().manual_seed(5))).requires_grad_(True)

    def f(p, d):
        R, tr, present = torch.func.functional_call(traj, {"positions": p, "rotation_deltas": d}, (0.137,))
        mw, qw, _ = compose_gaussians(means, quats, ids, R, tr, present, traj.instance_ids)
        return mw, qw

    assert torch.autograd.gradcheck(f, (pos, rot))
