"""Lidar rasterizer extras used by training: culling of Gaussians no ray can see (same output),
and the line-of-sight output (alpha summed before a per-ray cut-off) against a dense reference."""

import math

import torch

from idsplat_ns.render import rasterize_lidar
from idsplat_ns.render.lidar import seen_by_rays


def _scene(n: int, seed: int, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) * torch.tensor([1, 1, 0.2]), dim=1)
    means = dirs * (3 + 15 * torch.rand(n, 1, generator=g))
    means[0] = torch.tensor([0.5, 0.4, 0.1])  # a Gaussian right beside the sensor spans every direction
    params = [means, torch.randn(n, 4, generator=g), torch.rand(n, 3, generator=g) * 0.5 + 0.1,
              torch.rand(n, generator=g) * 0.9 + 0.05, torch.rand(n, 3, generator=g)]  # fmt: skip
    return [p.to(dtype).requires_grad_() for p in params], g


def test_culling_keeps_the_output_and_gradients_of_a_sector_of_rays():
    params, g = _scene(400, 3)
    # Rays in a 40-degree sector (one time bin of a spinning lidar), the rest of the circle empty.
    r = 300
    az = torch.deg2rad(torch.rand(r, generator=g) * 40 + 10).double()
    el = torch.deg2rad(torch.rand(r, generator=g) * 20 - 10).double()
    el[-40:] = torch.deg2rad(torch.rand(40, generator=g) * 15 + 70).double()  # some rays near the zenith
    with torch.no_grad():
        # Near the zenith at azimuth 120 degrees, outside the sector in azimuth but not on the sphere.
        el0, az0 = math.radians(80), math.radians(120)
        params[0][1] = 8 * torch.tensor([math.cos(el0) * math.cos(az0), math.cos(el0) * math.sin(az0), math.sin(el0)])
        params[2][1] = 0.6
        params[3][1] = 0.9
    kw = dict(azimuth_resolution=math.radians(0.5), elevation_resolution=math.radians(0.5))
    pose = torch.eye(4, dtype=torch.float64)
    a = rasterize_lidar(*params, pose, az, el, cull=True, **kw)
    b = rasterize_lidar(*params, pose, az, el, cull=False, **kw)
    seen = seen_by_rays(params[0].detach()[None], params[2].detach(), pose[None], az, el,
                        torch.zeros(r, dtype=torch.int64), math.radians(5.0))  # fmt: skip
    assert seen.shape == (1, params[0].shape[0])
    assert bool(seen[0, 0]) and bool(seen[0, 1]) and 0.1 < seen.float().mean() < 0.6  # most are culled, not these
    assert (b.alpha > 0.3).float().mean() > 0.2 and (b.alpha[-40:] > 0.01).any()
    for name in ("features", "alpha", "range", "median_range"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name), atol=1e-9, rtol=1e-9)
    ga = torch.autograd.grad(a.features.square().sum() + a.range_unnormalised.sum(), params)
    gb = torch.autograd.grad(b.features.square().sum() + b.range_unnormalised.sum(), params)
    for x, y in zip(ga, gb):
        torch.testing.assert_close(x, y, atol=1e-9, rtol=1e-9)


def _dense_line_of_sight(means, quats, scales, opac, az, el, cutoff, az_res, el_res):
    """Every Gaussian against every ray (test reference): sum of the alphas of the composited
    Gaussians (gsplat's skip and early-stop rules) whose range is below the ray's cut-off."""
    from idsplat_ns.render.lidar import project_spherical
    from idsplat_ns.render.projection import covariance_3d
    from idsplat_ns.render.reference import TRANSMITTANCE_MIN

    proj = project_spherical(means[None], covariance_3d(quats, scales)[None], torch.eye(4, dtype=means.dtype)[None],
                             az_res, el_res, -math.pi, 10**6)  # fmt: skip
    width = 2 * math.pi / az_res
    order = torch.argsort(proj.ranges[0].detach())
    m, c, rng = proj.means2d[0][order], proj.conics[0][order], proj.ranges[0][order].detach()
    dx = m[None, :, 0] - (torch.remainder(az, 2 * math.pi) / az_res)[:, None]
    dx = dx - width * torch.round(dx / width)
    dy = m[None, :, 1] - ((el + math.pi) / el_res)[:, None]
    sig = (0.5 * (c[None, :, 0] * dx * dx + c[None, :, 2] * dy * dy) + c[None, :, 1] * dx * dy).clamp_min(0)
    alpha = torch.clamp_max(opac[order][None] * torch.exp(-sig), 0.999)
    alpha = torch.where((alpha >= 1 / 255) & (proj.radii[0][order] > 0)[None], alpha, 0.0)
    kept = torch.cumprod(1 - alpha, dim=1) > TRANSMITTANCE_MIN  # gsplat's early stop
    front = kept & (rng[None, :] < cutoff[:, None])
    return (alpha * front).sum(1, keepdim=True)


def test_line_of_sight_output_equals_dense_reference_forward_and_gradients():
    params, g = _scene(300, 1)
    with torch.no_grad():
        params[0][0] = torch.tensor([6.0, 0.3, 0.1])  # the near one moved out of the way
    r = 400
    az = ((torch.rand(r, generator=g) * 2 - 1) * math.pi).double()
    el = torch.deg2rad(torch.rand(r, generator=g) * 30 - 15).double()
    cutoff = (4 + 14 * torch.rand(r, generator=g)).double()
    cutoff[:20] = 0.0  # nothing is in front of a zero cut-off
    res = math.radians(1.0)
    out = rasterize_lidar(*params, torch.eye(4, dtype=torch.float64), az, el, azimuth_resolution=res,
                          elevation_resolution=res, tile_size=4, ray_cutoff=cutoff)  # fmt: skip
    plain = rasterize_lidar(*params, torch.eye(4, dtype=torch.float64), az, el, azimuth_resolution=res,
                            elevation_resolution=res, tile_size=4)  # fmt: skip
    assert plain.alpha_before_cutoff is None  # only computed when asked
    torch.testing.assert_close(out.features, plain.features)  # the extra output changes nothing else
    az_res = 2 * math.pi / (4 * round(2 * math.pi / res / 4))
    ref = _dense_line_of_sight(params[0], params[1], params[2], params[3], az, el, cutoff, az_res, res)
    assert (ref > 0.1).float().mean() > 0.2 and (ref[:20] == 0).all()
    torch.testing.assert_close(out.alpha_before_cutoff, ref, atol=1e-6, rtol=1e-5)
    weights = torch.rand(r, 1, generator=g).double()  # a generic upstream gradient
    g1 = torch.autograd.grad((out.alpha_before_cutoff * weights).sum() + out.alpha.sum(), params[:4])
    g2 = torch.autograd.grad((ref * weights).sum() + plain.alpha.sum(), params[:4])
    for x, y in zip(g1, g2):
        torch.testing.assert_close(x, y, atol=2e-4, rtol=1e-3)


def test_sub_tiles_of_any_size_give_the_same_render_and_gradients(monkeypatch):
    # Rays bunched unevenly (a dense patch and a sparse spread): tiles hold from 1 to many rays.
    import idsplat_ns.render.lidar as lidar

    params, g = _scene(300, 5)
    az = torch.cat([torch.rand(150, generator=g) * 0.02 + 0.5, torch.rand(150, generator=g) * 6.2]).double()
    el = (torch.rand(300, generator=g) * 0.3 - 0.15).double()
    cutoff = torch.rand(300, generator=g).double() * 15
    kw = dict(azimuth_resolution=math.radians(0.5), elevation_resolution=math.radians(0.5), ray_cutoff=cutoff)
    chosen = []
    real = lidar.sub_tile_slots
    monkeypatch.setattr(lidar, "sub_tile_slots", lambda per_tile, pairs: chosen.append(real(per_tile, pairs)) or chosen[-1])
    auto = rasterize_lidar(*params, torch.eye(4, dtype=torch.float64), az, el, **kw)
    fullest = None
    for size in (1, 3, "fullest"):
        if size == "fullest":
            monkeypatch.setattr(lidar, "sub_tile_slots", lambda per_tile, pairs: int(per_tile.max()))
        else:
            monkeypatch.setattr(lidar, "sub_tile_slots", lambda per_tile, pairs, s=size: s)
        out = rasterize_lidar(*params, torch.eye(4, dtype=torch.float64), az, el, **kw)
        for name in ("features", "alpha", "range", "median_range", "alpha_before_cutoff"):
            torch.testing.assert_close(getattr(out, name), getattr(auto, name), atol=1e-9, rtol=1e-9)
        ga = torch.autograd.grad(auto.features.square().sum() + auto.range_unnormalised.sum(), params, retain_graph=True)
        gb = torch.autograd.grad(out.features.square().sum() + out.range_unnormalised.sum(), params)
        for x, y in zip(ga, gb):
            torch.testing.assert_close(x, y, atol=1e-9, rtol=1e-9)
        fullest = out
    assert (fullest.alpha > 0.1).float().mean() > 0.2
    assert 1 < chosen[0] < 150  # the dense patch is dealt into several sub-tiles


def test_sub_tile_slots_and_split_tiles_by_hand():
    from idsplat_ns.render.lidar import split_tiles, sub_tile_slots

    per_tile = torch.tensor([5, 0, 1, 2])
    offsets = torch.tensor([0, 2, 3, 3, 6])  # runs of 2, 1, 0 and 3 intersections
    first, sub_offsets, src = split_tiles(per_tile, offsets, 2)
    assert first.tolist() == [0, 3, 3, 4]  # tile 0 has 3 sub-tiles, tile 1 none, tiles 2 and 3 one each
    assert sub_offsets.tolist() == [0, 2, 4, 6, 6, 9]
    assert src.tolist() == [0, 1, 0, 1, 0, 1, 3, 4, 5]
    # One tile of 40 rays among tiles of 1 (same list lengths): sub-tiles of a few rays, not 40.
    assert 1 < sub_tile_slots(torch.tensor([40] + [1] * 30), torch.full((31,), 10)) < 10
    assert sub_tile_slots(torch.tensor([4, 4, 4]), torch.tensor([10, 10, 10])) == 4
    assert sub_tile_slots(torch.zeros(3, dtype=torch.int64), torch.zeros(3, dtype=torch.int64)) == 1
