"""Lidar rasterizer: analytic ranges, wrap-around continuity, dense reference, poles."""

import math

import pytest
import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.render import rasterize_lidar
from idsplat_ns.render.lidar import project_spherical
from idsplat_ns.render.projection import covariance_3d
from idsplat_ns.render.reference import composite_weights


def _dir(az_deg, el_deg):
    az, el = math.radians(az_deg), math.radians(el_deg)
    return torch.tensor([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def _one(mean, scale=0.1, opacity=0.8):
    return (mean[None], torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), scale),
            torch.tensor([opacity]), torch.tensor([[0.5, 2.0]]))  # fmt: skip


def test_single_gaussian_gives_its_range_and_the_analytic_falloff():
    mean = 10.0 * _dir(30, 5)
    az = torch.tensor([math.radians(30), math.radians(30.3), math.radians(-150)])
    el = torch.tensor([math.radians(5), math.radians(5), 0.0])
    out = rasterize_lidar(*_one(mean), torch.eye(4), az, el)
    assert out.alpha[0, 0].item() == pytest.approx(0.8, rel=1e-5)
    assert out.range[0, 0].item() == pytest.approx(10.0, rel=1e-5)
    assert out.median_range[0, 0].item() == pytest.approx(10.0, rel=1e-5)
    torch.testing.assert_close(out.features[0], 0.8 * torch.tensor([0.5, 2.0]))
    # Azimuth std = scale / horizontal distance, in 0.2 degree units, plus the 0.3 low-pass.
    res = 2 * math.pi / (8 * round(2 * math.pi / math.radians(0.2) / 8))
    sigma_u = 0.1 / (10 * math.cos(math.radians(5))) / res
    du = math.radians(0.3) / res
    expect = 0.8 * math.exp(-0.5 * du**2 / (sigma_u**2 + 0.3))
    assert out.alpha[1, 0].item() == pytest.approx(expect, rel=2e-3)
    assert out.alpha[2, 0].item() == 0.0 and out.range[2, 0].item() == 0.0


def test_wall_of_gaussians_gives_the_plane_distance():
    # A wall x = 20 m of overlapping opaque Gaussians; rays hit it at 20 / (cos az cos el).
    ys, zs = torch.meshgrid(torch.arange(-8, 8.01, 0.1), torch.arange(-3, 3.01, 0.1), indexing="ij")
    n = ys.numel()
    means = torch.stack([torch.full((n,), 20.0), ys.reshape(-1), zs.reshape(-1)], 1)
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
    scales = torch.tensor([[0.01, 0.1, 0.1]]).repeat(n, 1)
    az_deg = torch.tensor([0.0, 5.0, -10.0, 12.0])
    el_deg = torch.tensor([0.0, 3.0, -4.0, 1.5])
    out = rasterize_lidar(means, quats, scales, torch.full((n,), 0.9), torch.ones(n, 1), torch.eye(4),
                          torch.deg2rad(az_deg), torch.deg2rad(el_deg))  # fmt: skip
    # Exact hit distance along the ray direction to the plane x = 20.
    dirs = torch.stack([_dir(a, e) for a, e in zip(az_deg.tolist(), el_deg.tolist())])
    expect = 20.0 / dirs[:, 0]
    assert (out.alpha[:, 0] > 0.999).all()
    torch.testing.assert_close(out.range[:, 0], expect, atol=0.03, rtol=0)
    torch.testing.assert_close(out.median_range[:, 0], expect, atol=0.1, rtol=0)


def test_azimuth_wraps_around_continuously():
    # A Gaussian straddling +-180 degrees: rays just either side see the same thing.
    mean = 15.0 * _dir(180, 0)
    eps = 0.05
    az = torch.deg2rad(torch.tensor([180 - eps, -180 + eps, 180 - 3 * eps, -180 + 3 * eps, 180.0]))
    out = rasterize_lidar(*_one(mean, scale=0.2), torch.eye(4), az, torch.zeros(5))
    assert out.alpha[4, 0].item() == pytest.approx(0.8, rel=1e-5)
    torch.testing.assert_close(out.alpha[0], out.alpha[1], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(out.alpha[2], out.alpha[3], rtol=1e-4, atol=1e-6)
    assert out.alpha[2, 0] < out.alpha[0, 0] < out.alpha[4, 0]
    torch.testing.assert_close(out.range[:, 0], torch.full((5,), 15.0))


def _dense_lidar(means, quats, scales, opac, feats, az, el, az_res, el_res):
    """Every Gaussian against every ray with the same spherical projection (test reference)."""
    proj = project_spherical(means[None], covariance_3d(quats, scales)[None], torch.eye(4, dtype=means.dtype)[None],
                             az_res, el_res, -math.pi, 10**6)  # fmt: skip
    width = 2 * math.pi / az_res
    order = torch.argsort(proj.ranges[0].detach())
    m, c = proj.means2d[0][order], proj.conics[0][order]
    ru = torch.remainder(az, 2 * math.pi) / az_res
    rv = (el + math.pi) / el_res
    dx = m[None, :, 0] - ru[:, None]
    dx = dx - width * torch.round(dx / width)
    dy = m[None, :, 1] - rv[:, None]
    sig = (0.5 * (c[None, :, 0] * dx * dx + c[None, :, 2] * dy * dy) + c[None, :, 1] * dx * dy).clamp_min(0)
    alpha = torch.clamp_max(opac[order][None] * torch.exp(-sig), 0.999)
    alpha = torch.where((alpha >= 1 / 255) & (proj.radii[0][order] > 0)[None], alpha, 0.0)
    w, _ = composite_weights(alpha)
    return w @ feats[order], w.sum(1, keepdim=True), w @ proj.ranges[0][order][:, None]


def test_spherical_covariance_is_the_autograd_jacobian_sandwich():
    # The projected covariance against J S J^T + eps2d, J the autograd Jacobian of the world point's
    # (u, v) (an independent reference, no closed form shared), with a turned and moved sensor; then
    # gradcheck of the conics and covariances w.r.t. means and (non-symmetric) covariances, float64.
    f64 = torch.float64
    g = torch.Generator().manual_seed(7)
    n = 16
    means = torch.randn(n, 3, generator=g, dtype=f64) * 6 + torch.tensor([4.0, -3.0, 1.0], dtype=f64)
    a = torch.randn(n, 3, 3, generator=g, dtype=f64) * 0.3
    covars = a @ a.transpose(1, 2)
    q = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=f64))[0]
    pose = torch.eye(4, dtype=f64)
    pose[:3, :3] = q * torch.sign(torch.linalg.det(q))
    pose[:3, 3] = torch.tensor([1.0, 2.0, -0.5], dtype=f64)
    az_res, el_res, el_min, eps = math.radians(0.2), math.radians(0.3), math.radians(-60.0), 0.3
    proj = project_spherical(means[None], covars[None], pose[None], az_res, el_res, el_min, 400, eps2d=eps)

    def uv(p):
        s = pose[:3, :3] @ p + pose[:3, 3]
        return torch.stack([torch.atan2(s[1], s[0]) / az_res, (torch.atan2(s[2], torch.hypot(s[0], s[1])) - el_min) / el_res])

    for i in range(n):
        jac = torch.autograd.functional.jacobian(uv, means[i])
        c = jac @ covars[i] @ jac.T
        expect = torch.stack([c[0, 0] + eps, c[0, 1], c[1, 1] + eps])
        torch.testing.assert_close(proj.covars2d[0, i], expect, rtol=1e-10, atol=1e-10)

    def project(m, c):
        out = project_spherical(m[None], c[None], pose[None], az_res, el_res, el_min, 400, eps2d=eps)
        return out.conics, out.covars2d, out.means2d

    skew = torch.randn(4, 3, 3, generator=g, dtype=f64) * 0.01  # every entry is read as given
    assert torch.autograd.gradcheck(project, (means[:4].clone().requires_grad_(), (covars[:4] + skew).requires_grad_()))


def test_lidar_equals_dense_reference_forward_and_gradients():
    g = torch.Generator().manual_seed(1)
    n = 300
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) * torch.tensor([1, 1, 0.2]), dim=1)
    means = dirs * (5 + 10 * torch.rand(n, 1, generator=g))
    params = [means, torch.randn(n, 4, generator=g), torch.rand(n, 3, generator=g) * 0.6 + 0.2,
              torch.rand(n, generator=g) * 0.9 + 0.05, torch.rand(n, 3, generator=g)]  # fmt: skip
    params = [p.double().requires_grad_() for p in params]  # float64: no 1/255 rounding flips
    r = 400
    az = ((torch.rand(r, generator=g) * 2 - 1) * math.pi).double()
    el = torch.deg2rad(torch.rand(r, generator=g) * 30 - 15).double()
    res = math.radians(1.0)
    out = rasterize_lidar(*params, torch.eye(4, dtype=torch.float64), az, el, azimuth_resolution=res,
                          elevation_resolution=res, tile_size=4)  # fmt: skip
    az_res = 2 * math.pi / (4 * round(2 * math.pi / res / 4))
    f, a, dsum = _dense_lidar(*params, az, el, az_res, res)
    assert (a > 0.3).float().mean() > 0.2
    torch.testing.assert_close(out.features, f, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(out.alpha, a, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(out.range * out.alpha, dsum, atol=1e-4, rtol=1e-4)
    g1 = torch.autograd.grad(out.features.square().sum() + (out.range * out.alpha).sum(), params)
    g2 = torch.autograd.grad(f.square().sum() + dsum.sum(), params)
    for x, y in zip(g1, g2):
        torch.testing.assert_close(x, y, atol=2e-4, rtol=1e-3)


def test_rays_straight_up_and_down_are_finite():
    means = torch.tensor([[0.0, 0.0, 10.0], [0.0, 0.0, -4.0], [3.0, 0.0, 0.0]], requires_grad=True)
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(3, 1)
    scales = torch.full((3, 3), 0.2)
    az = torch.tensor([0.0, 1.0, 0.0])
    el = torch.tensor([math.pi / 2, -math.pi / 2, 0.0])
    out = rasterize_lidar(means, quats, scales, torch.full((3,), 0.9), torch.ones(3, 1), torch.eye(4), az, el)
    torch.testing.assert_close(out.range[:, 0], torch.tensor([10.0, 4.0, 3.0]), atol=1e-3, rtol=0)
    (out.range.sum() + out.alpha.sum()).backward()
    assert torch.isfinite(means.grad).all()


def test_time_bins_use_their_own_gaussian_positions():
    # One Gaussian moving from azimuth 0 to 90 degrees between two bins of a sweep.
    means = torch.stack([10.0 * _dir(0, 0), 10.0 * _dir(90, 0)])[:, None, :]
    quats = torch.tensor([1.0, 0, 0, 0]).expand(2, 1, 4)
    az = torch.deg2rad(torch.tensor([0.0, 90.0, 0.0, 90.0]))
    bins = torch.tensor([0, 0, 1, 1])
    out = rasterize_lidar(means, quats, torch.full((1, 3), 0.1), torch.tensor([0.8]), torch.ones(1, 1),
                          torch.eye(4).expand(2, 4, 4), az, torch.zeros(4), ray_bins=bins)  # fmt: skip
    torch.testing.assert_close(out.alpha[:, 0], torch.tensor([0.8, 0.0, 0.0, 0.8]))


def test_time_bins_with_their_own_gaussians():
    # Bin 0 has one Gaussian at azimuth 0, bin 1 two (azimuth 0 with another opacity, and 90):
    # per-bin scales, opacities and features, the short bin padded with opacity 0.
    means = torch.stack([torch.stack([10.0 * _dir(0, 0), torch.zeros(3)]),
                         torch.stack([10.0 * _dir(0, 0), 10.0 * _dir(90, 0)])])  # fmt: skip
    quats = torch.tensor([1.0, 0, 0, 0]).expand(2, 2, 4)
    opacities = torch.tensor([[0.8, 0.0], [0.5, 0.7]])
    features = torch.tensor([[[1.0], [0.0]], [[2.0], [3.0]]])
    az = torch.deg2rad(torch.tensor([0.0, 90.0, 0.0, 90.0]))
    bins = torch.tensor([0, 0, 1, 1])
    out = rasterize_lidar(means, quats, torch.full((2, 2, 3), 0.1), opacities, features, torch.eye(4).expand(2, 4, 4),
                          az, torch.zeros(4), ray_bins=bins)  # fmt: skip
    torch.testing.assert_close(out.alpha[:, 0], torch.tensor([0.8, 0.0, 0.5, 0.7]))
    torch.testing.assert_close(out.features[:, 0], torch.tensor([0.8, 0.0, 1.0, 2.1]))
    with pytest.raises(IDSplatError, match="per bin"):  # features of one Gaussian per bin for two: refused
        rasterize_lidar(means, quats, torch.full((2, 2, 3), 0.1), opacities, features[:, :1],
                        torch.eye(4).expand(2, 4, 4), az, torch.zeros(4), ray_bins=bins)  # fmt: skip
