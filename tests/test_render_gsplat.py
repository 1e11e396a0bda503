"""gsplat CUDA backend parity with the torch tile rasterizer (needs a CUDA GPU; skipped otherwise)."""

import pytest
import torch

from idsplat_ns.render import rasterize_camera

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="gsplat backend needs a CUDA GPU")


def test_gsplat_backend_matches_torch_backend():
    pytest.importorskip("gsplat")
    g = torch.Generator().manual_seed(0)
    n = 2000
    dev = torch.device("cuda")
    means = (torch.randn(n, 3, generator=g) * torch.tensor([1.0, 0.8, 0.5]) + torch.tensor([0, 0, 4.0])).to(dev)
    quats = torch.randn(n, 4, generator=g).to(dev)
    scales = (torch.rand(n, 3, generator=g) * 0.05 + 0.01).to(dev)
    opac = (torch.rand(n, generator=g) * 0.9 + 0.05).to(dev)
    feats = torch.rand(n, 5, generator=g).to(dev)
    vm = torch.eye(4, device=dev)[None]
    Ks = torch.tensor([[[100.0, 0, 64], [0, 100, 48], [0, 0, 1]]], device=dev)
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opac, feats)]
    a = rasterize_camera(*params, vm, Ks, 128, 96, backend="gsplat")
    b = rasterize_camera(*params, vm, Ks, 128, 96, backend="torch")
    # gsplat cuts Gaussians at its 3-sigma tile footprint: alpha there is < 0.011 * opacity.
    assert (a.features - b.features).abs().mean() < 2e-3
    assert (a.alpha - b.alpha).abs().max() < 2e-2
    ga = torch.autograd.grad(a.features.sum(), params)
    gb = torch.autograd.grad(b.features.sum(), params)
    for x, y in zip(ga, gb):
        assert torch.nn.functional.cosine_similarity(x.flatten(), y.flatten(), dim=0) > 0.99


def test_gsplat_rolling_shutter_and_instance_maps_match_torch_backend():
    # Two rolling-shutter cameras (readouts along rows and along columns, moving and turning),
    # moving Gaussians of three instances: the gsplat path (world means shifted per camera, one
    # call per camera) against the torch path (camera-frame shift inside the projection).
    pytest.importorskip("gsplat")
    from idsplat_ns.data.camera import RollingShutter
    from idsplat_ns.data.rolling_shutter import time_plane
    from idsplat_ns.render import CameraMotion, ShutterTiming

    dev = torch.device("cuda")
    g = torch.Generator().manual_seed(1)
    n, w, h = 1500, 96, 72
    means = (torch.randn(n, 3, generator=g) * torch.tensor([1.0, 0.8, 0.5]) + torch.tensor([0, 0, 4.0])).to(dev)
    quats = torch.randn(n, 4, generator=g).to(dev)
    scales = (torch.rand(n, 3, generator=g) * 0.05 + 0.01).to(dev)
    opac = (torch.rand(n, generator=g) * 0.9 + 0.05).to(dev)
    feats = torch.rand(n, 4, generator=g).to(dev)
    ids = torch.randint(0, 3, (n,), generator=g).to(dev)
    vel = (torch.randn(n, 3, generator=g) * 5.0).to(dev)
    vm = torch.eye(4, device=dev)[None].repeat(2, 1, 1)
    vm[1, 0, 3] = 0.3
    Ks = torch.tensor([[80.0, 0, 48], [0, 80, 36], [0, 0, 1]], device=dev)[None].repeat(2, 1, 1)
    timing = ShutterTiming.from_planes([time_plane(RollingShutter(0.04, "top_to_bottom"), w, h),
                                        time_plane(RollingShutter(0.03, "right_to_left"), w, h)], device=dev)
    motion = CameraMotion(timing, torch.tensor([[3.0, 0.0, 8.0], [0.0, 1.0, -2.0]], device=dev),
                          torch.tensor([[0.0, 0.3, 0.0], [0.1, 0.0, 0.2]], device=dev), vel)
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opac, feats)]
    kw = dict(instance_ids=ids, return_instance_alpha=True, motion=motion)
    a = rasterize_camera(*params, vm, Ks, w, h, backend="gsplat", **kw)
    b = rasterize_camera(*params, vm, Ks, w, h, backend="torch", **kw)
    assert (a.features - b.features).abs().mean() < 2e-3
    assert (a.alpha - b.alpha).abs().max() < 2e-2
    assert torch.equal(a.instance_values, b.instance_values)
    assert (a.instance_alpha - b.instance_alpha).abs().mean() < 2e-3
    covered = b.alpha[..., 0] > 0.5
    assert (a.instance_id[covered] == b.instance_id[covered]).float().mean() > 0.98
    # The shutter moved the picture: the global-shutter render differs where the torch one does.
    still = rasterize_camera(*params, vm, Ks, w, h, backend="gsplat", instance_ids=ids)
    assert (still.features - a.features).abs().mean() > 10 * (a.features - b.features).abs().mean()
    ga = torch.autograd.grad(a.features.sum(), params)
    gb = torch.autograd.grad(b.features.sum(), params)
    for x, y in zip(ga, gb):
        assert torch.nn.functional.cosine_similarity(x.flatten(), y.flatten(), dim=0) > 0.99
