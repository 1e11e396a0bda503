"""Camera tile rasterizer against the dense reference (forward, gradients, gradcheck)."""

import pytest
import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.render import project_gaussians, rasterize_camera, rasterize_dense


def _scene(n=300, seed=0, dtype=torch.float32, cams=2):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.0, 0.8, 0.5]) + torch.tensor([0, 0, 4.0])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.2 + 0.01
    opac = torch.rand(n, generator=g) * 0.98 + 0.01
    feats = torch.rand(n, 5, generator=g)
    viewmats = torch.eye(4)[None].repeat(cams, 1, 1)
    viewmats[1:, 0, 3] = 0.3
    Ks = torch.tensor([[40.0, 0, 18], [0, 40, 14], [0, 0, 1]])[None].repeat(cams, 1, 1)
    tensors = [t.to(dtype) for t in (means, quats, scales, opac, feats, viewmats, Ks)]
    return tensors, torch.randint(0, 4, (n,), generator=g)


def _dense(means, quats, scales, opac, feats, viewmats, Ks, w, h):
    p = project_gaussians(means, quats, scales, viewmats, Ks, w, h)
    return p, rasterize_dense(p.means2d, p.conics, p.depths, p.radii, opac, feats, w, h)


@pytest.mark.parametrize("tile_size", [4, 8, 16])
def test_tile_rasterizer_equals_dense_reference(tile_size):
    (means, quats, scales, opac, feats, vm, Ks), inst = _scene()
    w, h = 37, 29  # not a multiple of any tile size
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opac, feats, vm)]
    out = rasterize_camera(*params[:5], params[5], Ks, w, h, instance_ids=inst, tile_size=tile_size,
                           return_instance_alpha=True, backend="torch")  # fmt: skip
    _, (f, a, dsum, med, weights) = _dense(*params[:5], params[5], Ks, w, h)
    assert out.features.shape == (2, h, w, 5) and out.instance_id.shape == (2, h, w)
    assert (a > 0.5).float().mean() > 0.3 and (a == 0).any()  # a scene with both hit and empty pixels
    torch.testing.assert_close(out.features, f, atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(out.alpha, a, atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(out.median_depth, med, atol=1e-6, rtol=1e-6)
    dense_depth = torch.where(a > 0, dsum / a.clamp_min(1e-30), 0.0)
    torch.testing.assert_close(out.depth, dense_depth, atol=1e-5, rtol=1e-5)
    # Per-instance alpha: sums to alpha; the ID map is the argmax of the dense per-instance weights.
    torch.testing.assert_close(out.instance_alpha.sum(-1, keepdim=True), a, atol=2e-6, rtol=1e-5)
    onehot = torch.nn.functional.one_hot(inst, 4).float()
    dense_inst = (weights @ onehot).reshape(2, h, w, 4)
    torch.testing.assert_close(out.instance_alpha, dense_inst, atol=2e-6, rtol=1e-5)
    expect_id = torch.where(a[..., 0] > 0, dense_inst.argmax(-1), -1)
    assert (out.instance_id == expect_id).float().mean() > 0.999  # ties may break either way

    ours = (out.features.square().sum() + 3 * out.alpha.sum() + out.depth.sum()
            + out.median_depth.sum() + out.instance_alpha[..., 1].sum())  # fmt: skip
    ref = f.square().sum() + 3 * a.sum() + dense_depth.sum() + med.sum() + dense_inst[..., 1].sum()
    for g_ours, g_ref in zip(torch.autograd.grad(ours, params), torch.autograd.grad(ref, params)):
        torch.testing.assert_close(g_ours, g_ref, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("chunk_elems", [1 << 10, 1 << 24])
def test_compositor_block_size_never_changes_the_image(chunk_elems):
    # Small blocks (many carried transmittances) and one block for everything: both the dense image.
    (means, quats, scales, opac, feats, vm, Ks), _ = _scene()
    w, h = 37, 29
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opac, feats)]
    out = rasterize_camera(*params, vm, Ks, w, h, backend="torch", chunk_elems=chunk_elems)
    _, (f, a, *_rest) = _dense(*params, vm, Ks, w, h)
    torch.testing.assert_close(out.features, f, atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(out.alpha, a, atol=2e-6, rtol=1e-5)
    for g_ours, g_ref in zip(torch.autograd.grad(out.features.square().sum() + out.alpha.sum(), params),
                             torch.autograd.grad(f.square().sum() + a.sum(), params)):
        torch.testing.assert_close(g_ours, g_ref, atol=1e-4, rtol=1e-4)


def test_gradcheck_float64_tiny_scene():
    (means, quats, scales, opac, feats, vm, Ks), _ = _scene(n=6, seed=3, dtype=torch.float64, cams=1)
    opac = opac.clamp(0.2, 0.8)
    w, h = 10, 8
    Ks = torch.tensor([[[12.0, 0, 5], [0, 12, 4], [0, 0, 1]]], dtype=torch.float64)

    def fn(m, q, s, o, f, v):
        r = rasterize_camera(m, q, s, o, f, v, Ks, w, h, tile_size=4, backend="torch")
        return r.features, r.alpha, r.depth

    inputs = [t.clone().requires_grad_() for t in (means, quats, scales, opac, feats, vm)]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_empty_scene_and_all_culled():
    (means, quats, scales, opac, feats, vm, Ks), _ = _scene(n=10)
    means = means.clone()
    means[:, 2] = -3.0  # everything behind the camera
    means.requires_grad_()
    out = rasterize_camera(means, quats, scales, opac, feats, vm, Ks, 20, 10, backend="torch")
    assert out.alpha.abs().sum() == 0 and (out.instance_id == -1).all()
    assert out.depth.abs().sum() == 0 and out.median_depth.abs().sum() == 0
    out.features.sum().backward()
    assert torch.equal(means.grad, torch.zeros_like(means))


def test_single_opaque_gaussian_centre_pixel():
    # A round Gaussian at 2 m seen head-on: the centre pixel gets alpha = opacity, depth = 2.
    means = torch.tensor([[0.0, 0.0, 2.0]])
    quats = torch.tensor([[1.0, 0, 0, 0]])
    scales = torch.full((1, 3), 0.05)
    opac = torch.tensor([0.7])
    feats = torch.tensor([[0.2, 0.4, 0.6]])
    K = torch.tensor([[[100.0, 0, 10.5], [0, 100, 10.5], [0, 0, 1]]])
    out = rasterize_camera(means, quats, scales, opac, feats, torch.eye(4)[None], K, 21, 21,
                           instance_ids=torch.tensor([7]), backend="torch")  # fmt: skip
    assert out.alpha[0, 10, 10, 0].item() == pytest.approx(0.7, rel=1e-6)
    torch.testing.assert_close(out.features[0, 10, 10], 0.7 * feats[0])
    assert out.depth[0, 10, 10, 0].item() == pytest.approx(2.0, rel=1e-6)
    assert out.median_depth[0, 10, 10, 0].item() == pytest.approx(2.0, rel=1e-6)
    assert out.instance_id[0, 10, 10].item() == 7 and out.instance_id[0, 0, 0].item() == -1
    # sigma_2d = 100 * 0.05 / 2 = 2.5 px (+ eps2d blur): one pixel off centre follows the Gaussian.
    var = 2.5**2 + 0.3
    assert out.alpha[0, 10, 11, 0].item() == pytest.approx(0.7 * torch.exp(torch.tensor(-0.5 / var)).item(), rel=1e-5)


def test_bad_shapes_raise_one_line_errors():
    (means, quats, scales, opac, feats, vm, Ks), _ = _scene(n=5)
    with pytest.raises(IDSplatError, match="quats"):
        rasterize_camera(means, quats[:, :3], scales, opac, feats, vm, Ks, 8, 8)
    with pytest.raises(IDSplatError, match="backend"):
        rasterize_camera(means, quats, scales, opac, feats, vm, Ks, 8, 8, backend="vulkan")


def test_tile_coefficients_match_autograd_and_gradcheck():
    from idsplat_ns.render.tile_composite import TileCoefficients, quadratic_coefficients

    g = torch.Generator().manual_seed(0)
    scale = torch.tensor([8.0, 8.0, 2.0, 0.3, 2.0, 1.0], dtype=torch.float64)
    params = (torch.rand(20, 6, dtype=torch.float64, generator=g) * scale).requires_grad_()
    cx = torch.rand(20, dtype=torch.float64, generator=g) * 8
    cy = torch.rand(20, dtype=torch.float64, generator=g) * 8
    ours = TileCoefficients.apply(params, cx, cy)
    ref = quadratic_coefficients(params[:, 0] - cx, params[:, 1] - cy, params[:, 2:5], params[:, 5])
    upstream = torch.randn(20, 6, dtype=torch.float64, generator=g)
    torch.testing.assert_close(ours, ref, rtol=0, atol=0)
    g_ours = torch.autograd.grad(ours, params, upstream)[0]
    g_ref = torch.autograd.grad(ref, params, upstream)[0]
    torch.testing.assert_close(g_ours, g_ref, rtol=1e-12, atol=1e-12)
    assert torch.autograd.gradcheck(lambda q: TileCoefficients.apply(q, cx, cy), (params,))
    # Float32 inputs: float64 coefficients, float32 gradient.
    p32 = params.detach().float().requires_grad_()
    out32 = TileCoefficients.apply(p32, cx, cy)
    assert out32.dtype == torch.float64
    assert torch.autograd.grad(out32.sum(), p32)[0].dtype == torch.float32


def test_intersect_tiles_pairs_and_depth_order():
    from idsplat_ns.render.tiles import alpha_extent, intersect_tiles

    g = torch.Generator().manual_seed(1)
    cams, n, w, h, b = 2, 200, 37, 29, 8
    means2d = torch.rand(cams, n, 2, generator=g) * torch.tensor([w + 10.0, h + 10.0]) - 5
    var = torch.rand(cams, n, 2, generator=g) * 6 + 0.3
    covars = torch.stack([var[..., 0], 0.3 * var.prod(-1).sqrt(), var[..., 1]], -1)
    depths = torch.randn(cams, n, generator=g) * 3  # both signs: the integer sort keys must order them
    depths[0, :10] = depths[0, 10:20]  # ties keep their index order
    opac = torch.rand(n, generator=g) * 0.9 + 0.05
    radii = torch.ones(cams, n, dtype=torch.int32)
    isects = intersect_tiles(means2d, covars, depths, radii, opac, w, h, b)
    # Brute force: a pixel centre inside the alpha >= 1/255 box puts the Gaussian on the tile.
    ext = alpha_extent(covars.reshape(-1, 3), opac.repeat(cams)).reshape(cams, n, 2)
    px = torch.arange(w) + 0.5
    py = torch.arange(h) + 0.5
    expect, touch_none = set(), set()
    for c in range(cams):
        for i in range(n):
            mx, my = means2d[c, i]
            xs = px[(px >= mx - ext[c, i, 0]) & (px <= mx + ext[c, i, 0])]
            ys = py[(py >= my - ext[c, i, 1]) & (py <= my + ext[c, i, 1])]
            if ext[c, i, 0] < 0 or xs.numel() == 0 or ys.numel() == 0:
                touch_none.add(c * n + i)
                continue
            for ty in range(int(ys.min()) // b, int(ys.max()) // b + 1):
                for tx in range(int(xs.min()) // b, int(xs.max()) // b + 1):
                    expect.add((c * isects.tiles_x * isects.tiles_y + ty * isects.tiles_x + tx, c * n + i))
    got = set(zip(isects.tile_ids.tolist(), isects.gaussian_ids.tolist()))
    # Exact for Gaussians that reach a pixel; one whose box lies just off the image may be kept
    # on an edge tile (its alpha there is below 1/255: harmless).
    assert expect <= got and all(gid in touch_none for _, gid in got - expect)
    assert len(got - expect) < 0.2 * len(expect)
    flat = depths.reshape(-1)
    for t in range(isects.num_tiles):
        run = isects.gaussian_ids[isects.tile_offsets[t] : isects.tile_offsets[t + 1]]
        assert torch.equal(run, run[torch.sort(flat[run], stable=True).indices])  # front to back, ties by index
