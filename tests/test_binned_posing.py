"""Posing at K times in one batch (a lidar batch's time bins) against posing time by time: the
trajectories, the composition, the rasterizer's mixed per-bin/shared inputs and the binned lidar
render (values and gradients), so that the fast path is the reference's render."""

import math

import numpy as np
import torch

from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.model.composition import compose_gaussians, compose_gaussians_at_times, trajectory_index
from idsplat_ns.model.lidar_render import PosedBins, render_lidar_rays, render_lidar_rays_binned, sample_rays
from idsplat_ns.model.trajectories import InstanceTrajectories
from idsplat_ns.render import rasterize_lidar
from test_lidar_path import _dirs, _sweep, _wall

TIMES = np.arange(8) * 0.1


def _trajectories(dtype=torch.float64) -> InstanceTrajectories:
    """Instance 4 turning and moving over steps 1..6; instance 9 valid at steps 3..4 only."""
    f = len(TIMES)
    a = make_pose(rot_z(0.3 * np.arange(f)), np.stack([2.0 * np.arange(f), np.ones(f), np.zeros(f)], 1))
    b = make_pose(rot_z(np.full(f, -0.5)), np.stack([np.zeros(f), 3.0 * np.arange(f), np.ones(f)], 1))
    valid = np.zeros((2, f), bool)
    valid[0, 1:7] = True
    valid[1, 3:5] = True
    traj = InstanceTrajectories(TIMES, np.array([4, 9]), np.stack([a, b]), valid, span_margin=0.02, dtype=dtype)
    with torch.no_grad():  # refined rotations: the exponential map of the deltas is exercised too
        traj.rotation_deltas.copy_(0.05 * torch.randn(traj.rotation_deltas.shape, generator=torch.Generator().manual_seed(0)))
    return traj


def test_poses_at_times_equal_poses_at_each_time_values_and_gradients():
    traj = _trajectories()
    times = torch.tensor([0.0, 0.13, 0.35, 0.42, 0.79], dtype=torch.float64)  # before, inside, one-step span, after
    R, t, present = traj.poses_at_times(times)
    assert R.shape == (5, 2, 3, 3) and t.shape == (5, 2, 3) and present.shape == (5, 2)
    loss_batched = (R * torch.arange(9.0, dtype=R.dtype).view(3, 3)).sum() + t.square().sum()
    grads_batched = torch.autograd.grad(loss_batched, [traj.positions, traj.rotation_deltas])
    loss_each = 0
    for k, tk in enumerate(times.tolist()):
        Rk, tk_, pk = traj.poses_at(tk)
        torch.testing.assert_close(R[k], Rk, rtol=0, atol=1e-12)
        torch.testing.assert_close(t[k], tk_, rtol=0, atol=1e-12)
        assert torch.equal(present[k], pk)
        loss_each = loss_each + (Rk * torch.arange(9.0, dtype=Rk.dtype).view(3, 3)).sum() + tk_.square().sum()
    for x, y in zip(grads_batched, torch.autograd.grad(loss_each, [traj.positions, traj.rotation_deltas])):
        assert y.abs().sum() > 0
        torch.testing.assert_close(x, y, rtol=1e-10, atol=1e-12)
    # Presence as poses_at says it: instance 9 only around steps 3-4, instance 4 inside 1..6 (+ margin).
    assert present.tolist() == [[False, False], [True, False], [True, True], [True, True], [False, False]]


def test_a_scalar_tensor_time_keeps_its_gradient_without_a_host_read():
    traj = _trajectories()
    t = torch.tensor(0.25, dtype=torch.float64, requires_grad=True)
    _, trans, present = traj.poses_at(t)
    (speed,) = torch.autograd.grad(trans[0, 0], t)  # instance 4 moves 2 m per 0.1 s along x
    assert math.isclose(float(speed), 20.0, rel_tol=1e-9)
    assert present.tolist() == [True, False]


def test_trajectory_index_is_the_row_of_each_id_and_minus_one_elsewhere():
    traj_ids = torch.tensor([7, 3, 12])
    ids = torch.tensor([0, 3, 12, 5, 7, 7, -2, 40, 3])
    rows = {7: 0, 3: 1, 12: 2}
    assert trajectory_index(ids, traj_ids).tolist() == [rows.get(int(i), -1) if int(i) > 0 else -1 for i in ids]
    assert trajectory_index(ids, torch.zeros(0, dtype=torch.int64)).tolist() == [-1] * len(ids)


def test_compose_at_times_equals_composing_each_time():
    traj = _trajectories(torch.float32)
    gen = torch.Generator().manual_seed(1)
    n = 60
    ids = torch.tensor([0] * 20 + [4] * 20 + [9] * 15 + [5] * 5)  # 5 has no trajectory
    means = torch.randn(n, 3, generator=gen, requires_grad=True)
    quats = torch.randn(n, 4, generator=gen, requires_grad=True)
    times = torch.tensor([0.05, 0.31, 0.38, 0.6], dtype=torch.float64)
    R, t, present = traj.poses_at_times(times)
    m_k, q_k, keep_k = compose_gaussians_at_times(means, quats, ids, R, t, present, traj.instance_ids)
    assert m_k.shape == (4, n, 3) and q_k.shape == (4, n, 4) and keep_k.shape == (4, n)
    weights = torch.randn(4, n, 7, generator=gen)
    loss_batched = (torch.cat([m_k, q_k], -1) * weights * keep_k[..., None]).sum()
    loss_each = 0
    for k in range(4):
        m, q, keep = compose_gaussians(means, quats, ids, R[k], t[k], present[k], traj.instance_ids, drop=False)
        assert torch.equal(keep, keep_k[k])
        torch.testing.assert_close(m[keep], m_k[k][keep], rtol=0, atol=0)
        torch.testing.assert_close(q[keep], q_k[k][keep], rtol=0, atol=0)
        loss_each = loss_each + (torch.cat([m, q], -1) * weights[k] * keep[:, None]).sum()
    assert not keep_k[:, 55:].any() and keep_k[:, :20].all()  # no trajectory: never kept; background: always
    for x, y in zip(torch.autograd.grad(loss_batched, [means, quats]), torch.autograd.grad(loss_each, [means, quats])):
        torch.testing.assert_close(x, y, rtol=1e-6, atol=1e-6)


def test_rasterize_lidar_takes_per_bin_opacities_with_shared_scales_and_features():
    wall = _wall(15.0, step=0.25)
    n = wall.shape[0]
    gen = torch.Generator().manual_seed(2)
    means = torch.stack([wall, wall + torch.tensor([1.0, 0.0, 0.0])])  # [2, N, 3]
    quats = torch.randn(2, n, 4, generator=gen)
    scales = torch.full((n, 3), 0.1)
    opacities = torch.stack([torch.full((n,), 0.9), torch.rand(n, generator=gen)])
    features = torch.rand(n, 5, generator=gen)
    az = torch.tensor([0.0, 0.1, -0.1, 0.05])
    el = torch.tensor([0.0, 0.02, -0.03, 0.0])
    bins = torch.tensor([0, 1, 0, 1])
    pose = torch.eye(4).expand(2, 4, 4)
    mixed = rasterize_lidar(means, quats, scales, opacities, features, pose, az, el, ray_bins=bins, compositor="torch")
    full = rasterize_lidar(means, quats, scales.expand(2, n, 3), opacities, features.expand(2, n, 5), pose, az, el,
                           ray_bins=bins, compositor="torch")  # fmt: skip
    assert (mixed.alpha > 0.3).all()  # every ray hits its bin's wall
    for name in ("features", "alpha", "range", "median_range"):
        torch.testing.assert_close(getattr(mixed, name), getattr(full, name), rtol=0, atol=0)


def test_binned_render_equals_the_per_bin_reference_with_two_lidars_and_a_cut_off():
    # Two lidars 2 m apart, four time bins; a wall and a box that moves and exists for t < 0.06
    # only. The binned path (one posing, one cull) renders what the per-bin loop renders.
    gen = torch.Generator().manual_seed(4)
    wall, box = _wall(20.0, step=0.25), _wall(8.0, half_y=1.0, half_z=0.6, step=0.2)
    nw, nb = wall.shape[0], box.shape[0]
    means = torch.cat([wall, box]).requires_grad_(True)
    quats = torch.randn(nw + nb, 4, generator=gen).requires_grad_(True)
    scales = torch.empty(nw + nb, 3).uniform_(0.05, 0.2, generator=gen).requires_grad_(True)
    opacities = torch.full((nw + nb,), 0.9).requires_grad_(True)
    features = torch.rand(nw + nb, 6, generator=gen).requires_grad_(True)

    def posed_at(t: float) -> dict:
        moved = torch.cat([means[:nw], means[nw:] + torch.tensor([0.0, 10.0 * t, 0.0])])
        here = torch.cat([torch.ones(nw), torch.full((nb,), float(t < 0.06))])
        return {"means": moved, "quats": quats, "scales": scales, "opacities": opacities * here, "features": features}

    def posed_at_times(times: torch.Tensor) -> PosedBins:
        each = [posed_at(float(t)) for t in times]
        return PosedBins(torch.stack([p["means"] for p in each]), quats[None].expand(len(each), -1, -1),
                         torch.stack([p["opacities"] for p in each]), scales, features)

    n = 300
    rng = np.random.default_rng(7)
    origins = np.zeros((n, 3))
    origins[n // 2:, 0] = 2.0
    times = np.sort(rng.uniform(0.0, 0.1, n))
    sweep = _sweep(origins, _dirs(rng.uniform(-12, 12, n), rng.uniform(-3, 3, n)), times)
    sweep.sensor_ids[n // 2:] = 1
    rays = sample_rays(sweep, n)
    pose = torch.tensor(sweep.sensor_to_world, dtype=torch.float32)
    cutoff = torch.full((n,), 12.0)
    ref = render_lidar_rays(posed_at, rays, pose, num_time_bins=4, cutoff_ranges=cutoff, compositor="torch")
    fast = render_lidar_rays_binned(posed_at_times, rays, pose, num_time_bins=4, cutoff_ranges=cutoff, compositor="torch")
    assert ((ref.range[:, 0] > 0) & (ref.range[:, 0] < 12.0)).any() and (ref.range[:, 0] > 15.0).any()
    for name in ("features", "alpha", "range", "median_range", "alpha_before_cutoff"):
        torch.testing.assert_close(getattr(fast, name), getattr(ref, name), rtol=1e-5, atol=1e-5)
    params = [means, quats, scales, opacities, features]

    def loss(out):
        return out.features.square().sum() + (out.range * out.alpha).sum() + out.alpha_before_cutoff.sum()

    for x, y in zip(torch.autograd.grad(loss(fast), params), torch.autograd.grad(loss(ref), params)):
        assert y.abs().sum() > 0
        torch.testing.assert_close(x, y, atol=1e-4 * float(y.abs().max()), rtol=1e-4)
