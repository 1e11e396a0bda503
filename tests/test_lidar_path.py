"""Lidar path: ray sampling, time-binned rendering against analytic ranges, head, losses, metrics."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.eval.lidar_metrics import chamfer_distance, lidar_metrics
from idsplat_ns.model.lidar_head import LidarHead, LidarHeadOutput
from idsplat_ns.model.lidar_losses import LidarLossConfig, lidar_losses
from idsplat_ns.model.lidar_render import (
    LidarRayBatch,
    ray_angles,
    render_lidar_rays,
    sample_rays,
    time_bins,
)
from idsplat_ns.render import LidarRender


def _wall(
    x: float, half_y: float = 4.0, half_z: float = 2.0, step: float = 0.1
) -> torch.Tensor:
    """Means [N, 3] of a dense grid on the plane x = ``x``."""
    ys, zs = torch.meshgrid(
        torch.arange(-half_y, half_y + 1e-3, step),
        torch.arange(-half_z, half_z + 1e-3, step),
        indexing="ij",
    )
    return torch.stack(
        [torch.full((ys.numel(),), x), ys.reshape(-1), zs.reshape(-1)], 1
    )


def _gaussians(means: torch.Tensor, feature_dim: int = 13) -> dict:
    n = means.shape[0]
    return {
        "means": means,
        "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        "scales": torch.tensor([[0.01, 0.1, 0.1]]).repeat(n, 1),
        "opacities": torch.full((n,), 0.95),
        "features": torch.linspace(0, 1, feature_dim)[None].repeat(n, 1),
    }


def _yaw(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _dirs(az_deg, el_deg) -> np.ndarray:
    az, el = np.radians(az_deg), np.radians(el_deg)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)


def _sweep(origins, directions, times, ranges=None, returned=None) -> LidarSweep:
    n = len(origins)
    pose = np.eye(4)
    pose[:3, :3] = _yaw(
        35.0
    )  # a rotated sensor: angles must be taken in the sensor frame
    pose[:3, 3] = origins.mean(0)
    return LidarSweep(
        frame_index=0, time=float(np.mean(times)), raw_timestamp=0.0, sensor_to_world=pose,
        origins=origins, directions=directions,
        ranges=np.full(n, 10.0) if ranges is None else ranges, intensities=np.full(n, 0.5, np.float32),
        times=np.asarray(times, np.float64), returned=np.ones(n, bool) if returned is None else returned,
        sensor_ids=np.zeros(n, np.int16),
    )  # fmt: skip


def test_ray_angles_match_the_sensor_frame_convention():
    rot = torch.tensor(_yaw(35.0), dtype=torch.float32)
    # Sensor-frame direction at azimuth 20, elevation -7 degrees, rotated into the world.
    d_sensor = torch.tensor(
        _dirs(np.array([20.0]), np.array([-7.0])), dtype=torch.float32
    )
    az, el = ray_angles(d_sensor @ rot.T, rot)
    assert math.degrees(az.item()) == pytest.approx(20.0, abs=1e-4)
    assert math.degrees(el.item()) == pytest.approx(-7.0, abs=1e-4)


def test_sample_rays_subsamples_uniformly_without_replacement():
    n = 1000
    origins = np.zeros((n, 3))
    sweep = _sweep(origins, _dirs(np.linspace(-10, 10, n), np.zeros(n)), np.linspace(0, 0.1, n),
                   returned=np.arange(n) % 2 == 0)  # fmt: skip
    batch = sample_rays(sweep, 200, torch.Generator().manual_seed(0))
    assert batch.num_rays == 200 and batch.times.dtype == torch.float64
    assert len(set(batch.times.tolist())) == 200  # no repeats
    assert (
        70 < int(batch.returned.sum()) < 130
    )  # returned and dropped rays both sampled
    assert sample_rays(sweep, 5000).num_rays == n


def test_wall_range_is_the_analytic_plane_distance_from_each_rays_origin():
    # Sensor moving along x during the sweep: origins differ by up to 1 m; four time bins.
    n = 64
    rng = np.random.default_rng(0)
    times = np.linspace(0.0, 0.1, n)
    origins = np.stack([10.0 * times, np.zeros(n), np.zeros(n)], 1)  # 10 m/s
    az, el = rng.uniform(-8, 8, n), rng.uniform(-5, 5, n)
    dirs = _dirs(az, el)
    sweep = _sweep(origins, dirs, times)
    rays = sample_rays(sweep, n)
    gs = _gaussians(_wall(20.0))
    out = render_lidar_rays(
        lambda t: gs,
        rays,
        torch.tensor(sweep.sensor_to_world, dtype=torch.float32),
        num_time_bins=4,
    )
    expect = torch.tensor((20.0 - origins[:, 0]) / dirs[:, 0], dtype=torch.float32)
    assert (out.alpha[:, 0] > 0.99).all()
    torch.testing.assert_close(out.range[:, 0], expect, atol=0.03, rtol=0)
    torch.testing.assert_close(out.median_range[:, 0], expect, atol=0.1, rtol=0)
    # The composited features are the (constant) Gaussian features times alpha.
    torch.testing.assert_close(
        out.features, out.alpha * gs["features"][:1], atol=1e-4, rtol=0
    )


def test_each_lidar_is_cast_from_its_own_position():
    # Two lidars firing at the same times, 2 m apart along x (Waymo's TOP and FRONT are about that
    # far), rays 20-30 degrees off the wall normal. One mean origin for both would miss the wall
    # range by ~(1 m) sin^2/cos = 0.13-0.29 m; each from its own origin, it is the plane distance.
    n = 80
    rng = np.random.default_rng(1)
    origins = np.zeros((n, 3))
    origins[n // 2:, 0] = 2.0
    az, el = rng.uniform(20, 30, n), rng.uniform(-3, 3, n)
    dirs = _dirs(az, el)
    sweep = _sweep(origins, dirs, np.zeros(n))
    sweep.sensor_ids[n // 2:] = 2
    rays = sample_rays(sweep, n)
    assert rays.sensor_ids.tolist() == [0] * (n // 2) + [2] * (n // 2)
    gs = _gaussians(_wall(20.0, half_y=14.0, step=0.1))
    pose = torch.tensor(sweep.sensor_to_world, dtype=torch.float32)
    expect = torch.tensor((20.0 - origins[:, 0]) / dirs[:, 0], dtype=torch.float32)
    out = render_lidar_rays(lambda t: gs, rays, pose, num_time_bins=1)
    assert (out.alpha[:, 0] > 0.99).all()
    # The same as rendering each lidar's rays alone.
    halves = [torch.arange(n // 2), torch.arange(n // 2, n)]
    alone = [render_lidar_rays(lambda t: gs, _subset(rays, h), pose, num_time_bins=1).range for h in halves]
    torch.testing.assert_close(out.range, torch.cat(alone), atol=1e-5, rtol=0)
    # Within the splatting error of a 0.1 m grid of Gaussians seen obliquely; one mean origin is far off.
    own_error = (out.range[:, 0] - expect).abs().mean()
    merged = render_lidar_rays(lambda t: gs, replace(rays, sensor_ids=None), pose, num_time_bins=1)
    merged_error = (merged.range[:, 0] - expect).abs().mean()
    assert own_error < 0.08 and merged_error > 0.12 and merged_error > 2.5 * own_error


def test_time_bins_in_one_call_equal_each_bin_rendered_alone():
    # A moving sensor, a wall, and a car in front of it that moves and exists only in the first
    # half of the sweep: the bins differ in their Gaussians (count and positions), yet one
    # rasterization of all bins gives what rendering each bin's rays alone gives, gradients included.
    n = 400
    rng = np.random.default_rng(2)
    times = np.sort(rng.uniform(0.0, 0.1, n))
    origins = np.stack([10.0 * times, np.zeros(n), np.zeros(n)], 1)
    sweep = _sweep(origins, _dirs(rng.uniform(-10, 10, n), rng.uniform(-4, 4, n)), times)
    rays = sample_rays(sweep, n)
    wall = _gaussians(_wall(20.0, step=0.2))
    car = _gaussians(_wall(12.0, half_y=1.0, half_z=0.8, step=0.2), feature_dim=13)
    car["features"] = torch.rand(car["means"].shape[0], 13, generator=torch.Generator().manual_seed(0))
    params = [wall["means"].requires_grad_(), car["means"].requires_grad_(), car["opacities"].requires_grad_(),
              car["features"].requires_grad_()]  # fmt: skip

    def posed(t: float) -> dict:
        if t > 0.05:
            return wall
        moved = dict(car, means=car["means"] + torch.tensor([0.0, 20.0 * t, 0.0]))
        return {k: torch.cat([wall[k], moved[k]]) for k in wall}

    pose = torch.tensor(sweep.sensor_to_world, dtype=torch.float32)
    one = render_lidar_rays(posed, rays, pose, num_time_bins=4, cutoff_ranges=torch.full((n,), 15.0))
    bins, centres = time_bins(rays.times, 4)
    alone = {}
    for b in range(4):
        idx = torch.nonzero(bins == b).squeeze(1)
        alone[b] = (idx, render_lidar_rays(lambda t, b=b: posed(float(centres[b])), _subset(rays, idx), pose,
                                           num_time_bins=1, cutoff_ranges=torch.full((idx.numel(),), 15.0)))  # fmt: skip
    hits_car = torch.zeros(n, dtype=torch.bool)
    for name in ("features", "alpha", "range", "median_range", "alpha_before_cutoff"):
        expect = torch.zeros_like(getattr(one, name))
        for idx, out in alone.values():
            expect[idx] = getattr(out, name)
        torch.testing.assert_close(getattr(one, name), expect, atol=2e-5, rtol=1e-5)
    for idx, out in alone.values():
        hits_car[idx] = out.alpha_before_cutoff[:, 0] > 0.5
    assert 0.05 < hits_car.float().mean() < 0.5  # the car is in front of some rays, not all

    def loss(out_features, out_range, out_alpha):
        return out_features.square().sum() + (out_range * out_alpha).sum()

    g_one = torch.autograd.grad(loss(one.features, one.range, one.alpha), params)
    g_alone = torch.autograd.grad(sum(loss(o.features, o.range, o.alpha) for _, o in alone.values()), params)
    for x, y in zip(g_one, g_alone):
        assert x.abs().sum() > 0
        # Float32 rounding: the moving sensor's offset lands on the means (there) or on the sensor
        # pose (alone); on Gaussians 1 cm thin along the ray that moves a gradient by ~1e-3 of the
        # largest (with a still sensor the two agree to ~1e-5 of it).
        torch.testing.assert_close(x, y, atol=2e-3 * float(y.abs().max()), rtol=0)


@pytest.mark.parametrize("car_everywhere", [True, False])
def test_scene_model_poses_a_batch_like_activating_and_gathering_per_bin(car_everywhere):
    # SceneModel.render_lidar activates the Gaussians once for all time bins and skips the
    # gathers when every instance is present; against a poser that activates, composes and
    # gathers per bin (with the car present throughout, or gone after 0.05 s), values and the
    # gradients of every parameter group agree.
    from idsplat_ns.model.composition import compose_gaussians
    from idsplat_ns.model.gaussians import GaussianSet
    from idsplat_ns.model.scene_model import DecoderConfig, SceneModel
    from idsplat_ns.model.trajectories import InstanceTrajectories

    wall, car = _wall(20.0, step=0.25), _wall(0.0, half_y=1.0, half_z=0.8, step=0.25)
    g = GaussianSet(wall.shape[0] + car.shape[0])
    gen = torch.Generator().manual_seed(3)
    with torch.no_grad():
        g.means.copy_(torch.cat([wall, car]))
        g.scales.copy_(torch.empty(g.scales.shape).uniform_(math.log(0.05), math.log(0.2), generator=gen))
        g.quats.copy_(torch.randn(g.quats.shape, generator=gen))  # anisotropic: rotations get a gradient
        g.opacities.fill_(2.0)
        g.features.copy_(torch.rand(g.features.shape, generator=gen))
        g.instance_ids[wall.shape[0]:] = 1
    frame_times = np.array([0.0, 0.05, 0.1])
    poses = np.tile(np.eye(4), (1, 3, 1, 1))
    poses[0, :, 0, 3] = 12.0  # the car's canonical frame at x = 12 m, moving along y
    poses[0, :, 1, 3] = 20.0 * frame_times
    present = np.array([[True, True, car_everywhere]])
    traj = InstanceTrajectories(frame_times, np.array([1]), poses, present, refine=False)
    sm = SceneModel(g, 1, DecoderConfig(), traj, lidar_head_hidden=16)

    def per_bin(t: float) -> dict:
        a = g.activated()
        R, tr, here = traj.poses_at(t)
        means, quats, keep = compose_gaussians(a["means"], a["quats"], g.instance_ids, R, tr, here, traj.instance_ids)
        return {k: v[keep] for k, v in a.items()} | {"means": means, "quats": quats}

    n = 400
    rng = np.random.default_rng(5)
    times = np.sort(rng.uniform(0.0, 0.1, n))
    sweep = _sweep(np.zeros((n, 3)), _dirs(rng.uniform(-10, 10, n), rng.uniform(-4, 4, n)), times)
    rays = sample_rays(sweep, n)
    pose = torch.tensor(sweep.sensor_to_world, dtype=torch.float32)
    batch, _ = sm.render_lidar(rays, pose, num_time_bins=4)
    ref = render_lidar_rays(per_bin, rays, pose, num_time_bins=4)
    hits_car = (ref.range[:, 0] > 0) & (ref.range[:, 0] < 15.0)
    assert hits_car.any() and (ref.range[:, 0] > 15.0).any()
    for name in ("features", "alpha", "range", "median_range"):
        torch.testing.assert_close(getattr(batch, name), getattr(ref, name))
    # Transparent rows keep every per-Gaussian tensor row-aligned, velocities too (zero where absent).
    posed = sm.posed_gaussians(0.09, with_velocities=True, drop_absent=False)
    car_rows = g.instance_ids == 1
    assert posed["velocities"].shape == posed["means"].shape == g.means.shape
    assert torch.equal(posed["opacities"][car_rows] == 0, torch.full((int(car_rows.sum()),), not car_everywhere))
    if not car_everywhere:
        assert torch.equal(posed["velocities"][car_rows], torch.zeros(int(car_rows.sum()), 3))
    else:
        assert torch.allclose(posed["velocities"][car_rows], torch.tensor([0.0, 20.0, 0.0]).expand(int(car_rows.sum()), 3))
    params = [g.means, g.scales, g.quats, g.opacities, g.features]
    loss = lambda out: out.features.square().sum() + (out.range * out.alpha).sum()  # noqa: E731
    for x, y in zip(torch.autograd.grad(loss(batch), params), torch.autograd.grad(loss(ref), params)):
        assert y.abs().sum() > 0
        torch.testing.assert_close(x, y, atol=1e-5 * float(y.abs().max()), rtol=1e-5)


def test_each_bin_stacks_only_the_gaussians_its_rays_may_reach(monkeypatch):
    # A spinning sweep: the first half of the rays looks forward (azimuth near 0), the second half
    # backward (near 180). Walls in front and behind: each bin is given only its own wall.
    import idsplat_ns.model.lidar_render as lidar_render

    n = 200
    rng = np.random.default_rng(3)
    times = np.linspace(0.0, 0.1, n)
    az = np.where(np.arange(n) < n // 2, rng.uniform(-5, 5, n), rng.uniform(175, 185, n))
    sweep = _sweep(np.zeros((n, 3)), _dirs(az, rng.uniform(-3, 3, n)), times)
    rays = sample_rays(sweep, n)
    front, back = _wall(20.0, step=0.2), _wall(-20.0, step=0.2)
    gs = _gaussians(torch.cat([front, back]))
    sizes = []
    real = lidar_render.rasterize_lidar
    monkeypatch.setattr(lidar_render, "rasterize_lidar", lambda means, *a, **kw: sizes.append(means.shape[:2]) or real(means, *a, **kw))
    out = render_lidar_rays(lambda t: gs, rays, torch.tensor(sweep.sensor_to_world, dtype=torch.float32), num_time_bins=2)
    assert (out.alpha[:, 0] > 0.8).all()  # every ray hits its wall
    (groups, stacked), = sizes
    assert groups == 2 and stacked <= front.shape[0]  # not 2 x both walls


def _subset(rays: LidarRayBatch, idx: torch.Tensor) -> LidarRayBatch:
    return LidarRayBatch(rays.origins[idx], rays.directions[idx], rays.ranges[idx], rays.intensities[idx],
                         rays.times[idx], rays.returned[idx])


def test_time_bins_follow_the_moving_cluster_and_a_changing_gaussian_set():
    # A wall moving at 4 m/s along x; an extra blocker at x = 8 exists only for t > 0.5 s.
    wall = _wall(10.0, half_y=4.0, half_z=1.0)
    blocker = _wall(8.0, half_y=0.5, half_z=0.5)
    seen_times = []

    def posed_at(t: float) -> dict:
        seen_times.append(t)
        means = wall + torch.tensor([4.0 * t, 0.0, 0.0])
        if t > 0.5:
            means = torch.cat([means, blocker])
        return _gaussians(means)

    # Interleaved times so that scattering back into ray order is exercised.
    times = np.array([0.0, 1.0, 0.1, 0.9, 0.2, 1.0])
    dirs = _dirs(np.array([0.0, 0.0, 1.0, 1.0, -1.0, 10.0]), np.zeros(6))
    sweep = _sweep(np.zeros((6, 3)), dirs, times)
    rays = sample_rays(sweep, 6)
    out = render_lidar_rays(
        posed_at,
        rays,
        torch.tensor(sweep.sensor_to_world, dtype=torch.float32),
        num_time_bins=2,
    )
    assert seen_times == pytest.approx([0.25, 0.75])  # bin centres
    # Bin 0 (t < 0.5): wall at 10 + 4 * 0.25 = 11 m; bin 1: blocker at 8 m, except the ray at
    # 10 degrees azimuth, which passes beside the blocker to the wall at 13 m.
    plane = np.array([11.0, 8.0, 11.0, 8.0, 11.0, 13.0]) / dirs[:, 0]
    torch.testing.assert_close(
        out.range[:, 0], torch.tensor(plane, dtype=torch.float32), atol=0.03, rtol=0
    )
    bins, centres = time_bins(rays.times, 2)
    assert bins.tolist() == [0, 1, 0, 1, 0, 1] and centres.tolist() == pytest.approx(
        [0.25, 0.75]
    )


def test_losses_and_gradients_reach_gaussian_means_and_the_head():
    torch.manual_seed(0)
    n = 32
    times = np.linspace(0.0, 0.1, n)
    dirs = _dirs(np.linspace(-6, 6, n), np.linspace(-3, 3, n))
    returned = np.arange(n) % 4 != 0
    sweep = _sweep(
        np.zeros((n, 3)),
        dirs,
        times,
        ranges=np.where(returned, 19.0 / dirs[:, 0], 0.0),
        returned=returned,
    )
    rays = sample_rays(sweep, n)
    means = _wall(20.0).requires_grad_(True)
    gs = _gaussians(means) | {"means": means}
    head = LidarHead()
    out = render_lidar_rays(
        lambda t: gs, rays, torch.tensor(sweep.sensor_to_world, dtype=torch.float32)
    )
    losses = lidar_losses(out, head(out.features), rays, LidarLossConfig())
    # Range off by about 1 m on every returned ray: depth loss 0.1 * ~1.
    assert losses["lidar_depth"].item() == pytest.approx(0.1, rel=0.1)
    assert all(v.item() > 0 for v in losses.values())
    sum(losses.values()).backward()
    assert means.grad is not None and means.grad[:, 0].abs().sum() > 0
    # Pulling the wall nearer (x decreasing) reduces the depth loss: grad along +x is positive.
    assert means.grad[:, 0].sum() > 0
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters())


def _constructed(range_pred, intensity_pred, drop_logit, ranges, intensities, returned):
    r = len(ranges)
    rays = LidarRayBatch(torch.zeros(r, 3), torch.tensor([[1.0, 0, 0]]).repeat(r, 1), torch.tensor(ranges),
                         torch.tensor(intensities), torch.zeros(r, dtype=torch.float64), torch.tensor(returned))  # fmt: skip
    render = LidarRender(features=torch.zeros(r, 13), alpha=torch.ones(r, 1), range=torch.tensor(range_pred)[:, None],
                         median_range=torch.tensor(range_pred)[:, None])  # fmt: skip
    head = LidarHeadOutput(
        intensity=torch.tensor(intensity_pred), ray_drop_logit=torch.tensor(drop_logit)
    )
    return render, head, rays


def test_losses_are_zero_on_perfect_predictions_and_match_closed_forms():
    gt = {
        "ranges": [5.0, 7.0, 0.0],
        "intensities": [0.2, 0.6, 0.0],
        "returned": [True, True, False],
    }
    exact = LidarLossConfig(depth_quantile=1.0)  # closed forms over every returned ray
    perfect = lidar_losses(
        *_constructed([5.0, 7.0, 123.0], [0.2, 0.6, 0.9], [-30.0, -30.0, 30.0], **gt), exact
    )
    for v in perfect.values():
        assert v.item() == pytest.approx(0.0, abs=1e-9)
    # Range off by 2 m on one of two returned rays; intensity off by 0.1 on both; logits 0.
    off = lidar_losses(
        *_constructed([7.0, 7.0, 0.0], [0.3, 0.5, 0.0], [0.0, 0.0, 0.0], **gt), exact
    )
    assert off["lidar_depth"].item() == pytest.approx(0.1 * 4.0 / 2)
    assert off["lidar_intensity"].item() == pytest.approx(1.0 * 0.01)
    assert off["lidar_ray_drop"].item() == pytest.approx(0.1 * math.log(2.0))
    # Wrong drop decision: the no-return ray predicted as returned costs BCE 30 / 3 rays.
    wrong = lidar_losses(
        *_constructed([5.0, 7.0, 0.0], [0.2, 0.6, 0.0], [-30.0, -30.0, -30.0], **gt), exact
    )
    assert wrong["lidar_ray_drop"].item() == pytest.approx(0.1 * 30.0 / 3, rel=1e-6)
    assert "lidar_line_of_sight" not in wrong  # no cut-off render: no line-of-sight term


def test_default_losses_leave_out_the_worst_rays_and_use_the_unnormalised_range():
    # 20 returned rays measured at 10 m whose unnormalised range (alpha x range) is 10 + 0.1 i m,
    # half of them with alpha 0.5; 2 rays that returned nothing.
    i = torch.arange(20, dtype=torch.float32)
    alpha = torch.cat([torch.where(i % 2 == 0, 0.5, 1.0), torch.tensor([0.3, 0.3])])
    unnormalised = torch.cat([10.0 + 0.1 * i, torch.tensor([50.0, 50.0])])
    returned = torch.arange(22) < 20
    # Intensity is wrong only on ray 19 (the largest range error) and on the rays without a return;
    # the summed alpha before the cut-off is 0.2 on rays 0-18.
    intensity = torch.cat([torch.full((19,), 0.5), torch.tensor([0.9, 0.1, 0.1])])
    before_cutoff = torch.cat([torch.full((19,), 0.2), torch.tensor([5.0, 7.0, 7.0])])
    rays = LidarRayBatch(torch.zeros(22, 3), torch.tensor([[1.0, 0, 0]]).repeat(22, 1),
                         torch.where(returned, 10.0, 0.0), torch.where(returned, 0.5, 0.0),
                         torch.zeros(22, dtype=torch.float64), returned)  # fmt: skip
    render = LidarRender(features=torch.zeros(22, 13), alpha=alpha[:, None], range=(unnormalised / alpha)[:, None],
                         median_range=(unnormalised / alpha)[:, None], alpha_before_cutoff=before_cutoff[:, None])
    head = LidarHeadOutput(intensity=intensity, ray_drop_logit=torch.zeros(22))
    losses = lidar_losses(render, head, rays, LidarLossConfig())
    # Squared errors 0.01 i^2: the 95th percentile of the 20 lies between i = 18 and i = 19, so ray
    # 19 alone is left out of the depth, intensity and line-of-sight means. sum_{i<=18} i^2 = 2109.
    assert losses["lidar_depth"].item() == pytest.approx(0.1 * 0.01 * 2109 / 19, rel=1e-5)
    assert losses["lidar_intensity"].item() == pytest.approx(0.0, abs=1e-12)
    assert losses["lidar_line_of_sight"].item() == pytest.approx(0.1 * 0.2, rel=1e-6)
    assert losses["lidar_ray_drop"].item() == pytest.approx(0.1 * math.log(2.0), rel=1e-6)  # over all 22 rays


def test_head_shapes_and_ranges():
    head = LidarHead(feature_dim=13, hidden=32)
    assert [m.out_features for m in head.mlp if isinstance(m, torch.nn.Linear)] == [
        32,
        2,
    ]
    out = head(torch.randn(7, 13) * 10)
    assert out.intensity.shape == (7,) and out.ray_drop_logit.shape == (7,)
    assert ((out.intensity > 0) & (out.intensity < 1)).all()
    # Hand-set weights: hidden unit 0 copies feature 0 (then ReLU); output 0 is a constant
    # intensity of 0.3 after its sigmoid, output 1 the drop logit 2 + hidden unit 0.
    with torch.no_grad():
        for p in head.parameters():
            p.zero_()
        head.mlp[0].weight[0, 0] = 1.0
        head.mlp[-1].bias.copy_(torch.tensor([math.log(0.3 / 0.7), 2.0]))
        head.mlp[-1].weight[1, 0] = 1.0
    out = head(torch.tensor([[-3.0] + [0.0] * 12, [1.5] + [0.0] * 12]))
    torch.testing.assert_close(out.intensity, torch.tensor([0.3, 0.3]))
    torch.testing.assert_close(out.ray_drop_logit, torch.tensor([2.0, 3.5]))  # ReLU cut the negative input
    torch.testing.assert_close(out.ray_drop_prob, torch.tensor([1 / (1 + math.exp(-2.0)), 1 / (1 + math.exp(-3.5))]))


def test_chamfer_distance_closed_form():
    a = np.array([[0.0, 0.0, 0.0]])
    b = np.array([[1.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    # a -> b: 1; b -> a: (1 + 3) / 2 = 2; mean of both directions 1.5.
    assert chamfer_distance(a, b) == pytest.approx(1.5)
    assert chamfer_distance(b, a) == pytest.approx(1.5)
    pts = np.random.default_rng(0).normal(size=(50, 3))
    assert chamfer_distance(pts, pts) == 0.0
    assert math.isnan(chamfer_distance(np.zeros((0, 3)), b))


def test_lidar_metrics_on_hand_made_rays():
    x = np.array([1.0, 0.0, 0.0])
    origins = np.zeros((5, 3))
    directions = np.tile(x, (5, 1))
    gt_returned = np.array([True, True, True, False, False])
    gt_range = np.array([10.0, 10.0, 10.0, 0.0, 0.0])
    gt_int = np.array([0.5, 0.5, 0.5, 0.0, 0.0])
    pred_range = np.array([11.0, 13.0, 10.0, 10.0, 10.0])
    pred_int = np.array([0.6, 0.5, 0.3, 0.0, 0.0])
    pred_drop = np.array(
        [0.1, 0.2, 0.9, 0.8, 0.3]
    )  # ray 2 wrongly dropped, ray 4 wrongly returned
    m = lidar_metrics(
        pred_range,
        pred_int,
        pred_drop,
        gt_range,
        gt_int,
        gt_returned,
        origins,
        directions,
    )
    assert m["depth_median_sq"] == pytest.approx(
        np.median([1.0, 9.0])
    )  # rays 0 and 1 only
    assert m["intensity_rmse"] == pytest.approx(math.sqrt((0.01 + 0.0 + 0.04) / 3))
    assert m["ray_drop_accuracy"] == pytest.approx(3 / 5)
    # Predicted points at x = 11, 13, 10 (ray 4); GT points all at x = 10.
    # pred -> gt: (1 + 3 + 0) / 3; gt -> pred: 0 (the ray-4 point sits at x = 10).
    assert m["chamfer"] == pytest.approx(0.5 * (4 / 3 + 0.0))
