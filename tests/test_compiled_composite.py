"""The compiled CPU compositor against the torch compositor (values and gradients), its exp
against numpy's, and the ``compositor`` option's errors.

The dense reference checks of tests/test_render_camera.py and tests/test_render_lidar.py run on
the default compositor, which is the compiled one on the CPU; here both compositors are compared
on scenes built to reach every rule: the 1/255 skip, the 0.999 clamp, the early stop, empty
tiles, per-instance channels, lidar padding slots and the line-of-sight cut-off.
"""

import math
import threading

import numpy as np
import pytest
import torch

from idsplat_ns.errors import IDSplatError
from idsplat_ns.render import rasterize_camera, rasterize_lidar
from idsplat_ns.render import compiled_composite as cc
from idsplat_ns.render.compositor import use_compiled_compositor


def _camera_scene(dtype, n=400, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.0, 0.8, 0.5]) + torch.tensor([0, 0, 4.0])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.25 + 0.01
    opac = torch.rand(n, generator=g) * 0.98 + 0.01
    if n >= 80:
        opac[:40] = 1.0  # alpha reaches the 0.999 clamp near their centres
        means[40:80] = torch.tensor([0.1, 0.1, 3.0]) + 0.02 * torch.randn(40, 3, generator=g)  # an opaque stack: early stop
        scales[40:80] = 0.3
    feats = torch.rand(n, 4, generator=g)
    viewmats = torch.eye(4)[None].repeat(2, 1, 1)
    viewmats[1, 0, 3] = 0.4
    Ks = torch.tensor([[40.0, 0, 18], [0, 40, 14], [0, 0, 1]])[None].repeat(2, 1, 1)
    inst = torch.randint(0, 3, (n,), generator=g)
    return [t.to(dtype) for t in (means, quats, scales, opac, feats)], viewmats.to(dtype), Ks.to(dtype), inst


def _render_camera(compositor, params, viewmats, Ks, inst, tile_size=8):
    out = rasterize_camera(*params, viewmats, Ks, 45, 33, instance_ids=inst, tile_size=tile_size,
                           return_instance_alpha=True, backend="torch", compositor=compositor)  # fmt: skip
    loss = (out.features.square().sum() + 2 * out.alpha.sum() + out.depth.sum()
            + out.median_depth.sum() + out.instance_alpha[..., 1:2].sum())  # fmt: skip
    return out, torch.autograd.grad(loss, params)


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-9), (torch.float32, 2e-5)])
@pytest.mark.parametrize("tile_size", [4, 8])
def test_camera_compiled_equals_torch_compositor(dtype, tol, tile_size):
    base, vm, Ks, inst = _camera_scene(dtype)
    outs = {}
    for name in ("torch", "compiled"):
        params = [t.clone().requires_grad_() for t in base]
        outs[name] = _render_camera(name, params, vm, Ks, inst, tile_size)
    (ref, g_ref), (ours, g_ours) = outs["torch"], outs["compiled"]
    a = ref.alpha
    assert (a > 0.99).any() and (a == 0).any() and ((a > 0) & (a < 0.5)).any()  # stops, gaps and thin parts
    for name in ("features", "alpha", "depth", "instance_alpha"):
        torch.testing.assert_close(getattr(ours, name), getattr(ref, name), atol=tol, rtol=tol)
    # The median is a depth picked by a count: equal wherever T is not within rounding of 0.5.
    close = (ours.median_depth - ref.median_depth).abs() <= tol * (1 + ref.median_depth.abs())
    assert close.float().mean() > 0.999
    assert torch.equal(ours.instance_id, ref.instance_id) or dtype == torch.float32
    for x, y in zip(g_ours, g_ref):
        scale = y.abs().max().clamp_min(1.0)
        torch.testing.assert_close(x / scale, y / scale, atol=10 * tol, rtol=0)


def test_compiled_camera_has_finite_gradients_with_nothing_visible():
    base, vm, Ks, inst = _camera_scene(torch.float32, n=20)
    base[0] = base[0] - torch.tensor([0.0, 0.0, 10.0])  # every Gaussian behind the camera
    params = [t.clone().requires_grad_() for t in base]
    out, grads = _render_camera("compiled", params, vm, Ks, inst)
    assert (out.alpha == 0).all() and (out.instance_id == -1).all()
    assert all(torch.isfinite(g).all() and (g == 0).all() for g in grads)


def _lidar_scene(dtype, seed=1, n=300, bins=2):
    g = torch.Generator().manual_seed(seed)
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=g) * torch.tensor([1, 1, 0.2]), dim=1)
    means = dirs * (5 + 10 * torch.rand(n, 1, generator=g))
    per_bin_means = torch.stack([means + 0.05 * k for k in range(bins)])
    params = [per_bin_means, torch.randn(n, 4, generator=g).expand(bins, n, 4), torch.rand(n, 3, generator=g) * 0.6 + 0.2,
              torch.rand(n, generator=g) * 0.9 + 0.05, torch.rand(n, 3, generator=g)]  # fmt: skip
    r = 500
    az = (torch.rand(r, generator=g) * 2 - 1) * math.pi
    el = torch.deg2rad(torch.rand(r, generator=g) * 30 - 15)
    ray_bins = torch.randint(0, bins, (r,), generator=g)
    cutoff = 4 + 12 * torch.rand(r, generator=g)
    return [p.to(dtype) for p in params], az.to(dtype), el.to(dtype), ray_bins, cutoff.to(dtype)


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-9), (torch.float32, 2e-5)])
def test_lidar_compiled_equals_torch_compositor(dtype, tol):
    base, az, el, ray_bins, cutoff = _lidar_scene(dtype)
    lidar = torch.eye(4, dtype=dtype)[None].repeat(2, 1, 1)
    results = {}
    for name in ("torch", "compiled"):
        params = [t.clone().requires_grad_() for t in base]
        out = rasterize_lidar(*params, lidar, az, el, ray_bins=ray_bins, azimuth_resolution=math.radians(1.0),
                              elevation_resolution=math.radians(1.0), tile_size=4, ray_cutoff=cutoff,
                              compositor=name)  # fmt: skip
        loss = (out.features.square().sum() + (out.range * out.alpha).sum() + out.median_range.sum()
                + 3 * out.alpha_before_cutoff.sum())  # fmt: skip
        results[name] = out, torch.autograd.grad(loss, params)
    (ref, g_ref), (ours, g_ours) = results["torch"], results["compiled"]
    assert (ref.alpha > 0.3).float().mean() > 0.2 and (ref.alpha_before_cutoff > 0).any()
    assert ((ref.alpha_before_cutoff > 0) & (ref.alpha_before_cutoff < ref.alpha - 0.01)).any()  # cut-offs inside
    for name in ("features", "alpha", "range", "alpha_before_cutoff"):
        torch.testing.assert_close(getattr(ours, name), getattr(ref, name), atol=tol, rtol=tol)
    close = (ours.median_range - ref.median_range).abs() <= tol * (1 + ref.median_range.abs())
    assert close.float().mean() > 0.999
    for x, y in zip(g_ours, g_ref):
        scale = y.abs().max().clamp_min(1.0)
        torch.testing.assert_close(x / scale, y / scale, atol=10 * tol, rtol=0)


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-9), (np.float32, 2e-6)])
def test_exp_matches_numpy_over_the_alpha_range(dtype, tol):
    c = cc._CONSTANTS.astype(dtype)
    e = np.linspace(c[0], c[1], 200_001).astype(dtype)  # from the 0.999 clamp to below 1/255
    got = np.array([cc._exp_neg(x, c[7], c[5], *c[8:16]) for x in e[::97]])
    want = np.exp(-e[::97].astype(np.float64))
    assert np.max(np.abs(got / want - 1)) < tol


def test_compositor_option_errors_name_the_option():
    base, vm, Ks, inst = _camera_scene(torch.float32, n=10)
    with pytest.raises(IDSplatError, match="compositor='bogus'"):
        rasterize_camera(*base, vm, Ks, 45, 33, backend="torch", compositor="bogus")
    feats16 = base[4].to(torch.float16)
    with pytest.raises(IDSplatError, match="compositor='compiled' runs on float32/float64 CPU tensors"):
        use_compiled_compositor("compiled", feats16)
    assert not use_compiled_compositor("auto", feats16) and use_compiled_compositor("auto", base[4])


def test_two_threads_composite_at_once_and_agree():
    # Training and the viewer render from two Python threads, each dealing its tiles to the
    # worker pool; each tile's sums are one thread's, so the image is the same bit for bit.
    previous = torch.get_num_threads()
    torch.set_num_threads(2)  # so that each call deals tiles to a worker thread too
    base, vm, Ks, _ = _camera_scene(torch.float32)
    want = rasterize_camera(*base, vm, Ks, 45, 33, backend="torch", compositor="compiled").features
    results = [None, None]

    def work(k):
        for _ in range(3):
            results[k] = rasterize_camera(*base, vm, Ks, 45, 33, backend="torch", compositor="compiled").features

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    torch.set_num_threads(previous)
    assert all(torch.equal(r, want) for r in results)


def test_image_is_the_same_for_any_thread_count():
    # Tiles are dealt to the threads whole, so the count (and a pool grown on the way) never
    # changes a sum's order.
    base, vm, Ks, _ = _camera_scene(torch.float32)
    previous, images = torch.get_num_threads(), []
    for n in (2, 1, 3, 4, 2):
        torch.set_num_threads(n)
        images.append(rasterize_camera(*base, vm, Ks, 45, 33, backend="torch", compositor="compiled").features)
    torch.set_num_threads(previous)
    assert all(torch.equal(image, images[0]) for image in images)


def test_gradients_are_the_same_for_any_thread_count():
    # Each thread sums into buffers of its own (filled before the threads start), then they are
    # added: only the order of those sums changes with the count.
    base, vm, Ks, inst = _camera_scene(torch.float64)
    previous, grads = torch.get_num_threads(), []
    for n in (1, 3):
        torch.set_num_threads(n)
        params = [t.clone().requires_grad_() for t in base]
        grads.append(_render_camera("compiled", params, vm, Ks, inst)[1])
    torch.set_num_threads(previous)
    for x, y in zip(*grads):
        assert y.abs().max() > 0
        torch.testing.assert_close(x, y, atol=1e-12, rtol=1e-10)


def test_numba_is_loaded_only_when_the_compiled_loops_run(monkeypatch):
    # CUDA runs never load numba; an environment without it (the GPU benches' --target install)
    # gets the torch compositor under "auto" and a one-line error under "compiled".
    import subprocess
    import sys

    code = "import sys, idsplat_ns.render, idsplat_ns.render.camera, idsplat_ns.render.lidar; print('numba' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "False"
    from idsplat_ns.render import compositor

    monkeypatch.setattr(compositor, "numba_installed", lambda: False)
    feats = torch.zeros(3, 2)
    assert not compositor.use_compiled_compositor("auto", feats)
    with pytest.raises(IDSplatError, match="compositor='compiled' needs numba"):
        compositor.use_compiled_compositor("compiled", feats)
