"""The Triton compositor against the torch compositor (values and gradients), camera and lidar,
and the ``compositor`` option's choices and errors.

On a CUDA machine the kernels run compiled on the GPU (``bench/gpu_step.sh`` runs this file
there); elsewhere they run on CPU tensors in Triton's interpreter, which tests/conftest.py turns on
before anything imports Triton (slow: the scenes are small). The scenes reach every rule:
the 1/255 skip, the 0.999 clamp, the early stop, empty tiles, lidar padding slots, time bins and
the line-of-sight cut-off.
"""

import math
import os

import pytest
import torch

CUDA = torch.cuda.is_available()
# Without CUDA, tests/conftest.py has turned Triton's interpreter on before anything imported Triton.
assert CUDA or os.environ.get("TRITON_INTERPRET") == "1", "run these tests through pytest (tests/conftest.py)"

from idsplat_ns.errors import IDSplatError  # noqa: E402
from idsplat_ns.render import rasterize_camera, rasterize_lidar  # noqa: E402
from idsplat_ns.render import compositor  # noqa: E402
from idsplat_ns.render.tile_composite import (  # noqa: E402
    CompositePlan, TileComposite, monomial_basis, quadratic_coefficients,
)  # fmt: skip

DEVICE = "cuda" if CUDA else "cpu"
TOL = 2e-5  # float32 against float32: as the compiled compositor's test


def _camera_scene(n=60, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([0.6, 0.5, 0.3]) + torch.tensor([0, 0, 4.0])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.25 + 0.05
    opac = torch.rand(n, generator=g) * 0.98 + 0.01
    opac[:10] = 1.0  # alpha at the 0.999 clamp near their centres
    means[10:30] = torch.tensor([0.1, 0.1, 3.0]) + 0.02 * torch.randn(20, 3, generator=g)  # an opaque stack: early stop
    scales[10:30] = 0.3
    opac[10:30] = 0.9
    feats = torch.rand(n, 3, generator=g)
    viewmats = torch.eye(4)[None]
    Ks = torch.tensor([[20.0, 0, 12], [0, 20, 8], [0, 0, 1]])[None]
    return [t.to(DEVICE) for t in (means, quats, scales, opac, feats)], viewmats.to(DEVICE), Ks.to(DEVICE)


def _camera(name, params, viewmats, Ks):
    out = rasterize_camera(*params, viewmats, Ks, 24, 16, backend="torch", compositor=name)
    loss = out.features.square().sum() + 2 * out.alpha.sum() + out.depth.sum() + out.median_depth.sum()
    return out, torch.autograd.grad(loss, params)


def test_camera_triton_equals_torch_compositor():
    base, vm, Ks = _camera_scene()
    outs = {}
    for name in ("torch", "triton"):
        outs[name] = _camera(name, [t.clone().requires_grad_() for t in base], vm, Ks)
    (ref, g_ref), (ours, g_ours) = outs["torch"], outs["triton"]
    a = ref.alpha
    assert (a > 0.99).any() and (a == 0).any() and ((a > 0) & (a < 0.5)).any()  # stops, gaps and thin parts
    for name in ("features", "alpha", "depth"):
        torch.testing.assert_close(getattr(ours, name), getattr(ref, name), atol=TOL, rtol=TOL)
    close = (ours.median_depth - ref.median_depth).abs() <= TOL * (1 + ref.median_depth.abs())
    assert close.float().mean() > 0.99
    for x, y in zip(g_ours, g_ref):
        assert y.abs().max() > 0
        scale = y.abs().max().clamp_min(1.0)
        torch.testing.assert_close(x / scale, y / scale, atol=10 * TOL, rtol=0)


def _lidar_scene(n=60, rays=80, bins=2, seed=1):
    g = torch.Generator().manual_seed(seed)
    x = 5 + 6 * torch.rand(n, generator=g)  # ahead (+x), inside the rays' sector
    means = torch.stack([x, x * (torch.rand(n, generator=g) * 0.4 - 0.2), x * (torch.rand(n, generator=g) * 0.14 - 0.07)], 1)
    params = [torch.stack([means + 0.05 * k for k in range(bins)]), torch.randn(n, 4, generator=g).expand(bins, n, 4),
              torch.rand(n, 3, generator=g) * 0.3 + 0.15, torch.rand(n, generator=g) * 0.9 + 0.05,
              torch.rand(n, 3, generator=g)]  # fmt: skip
    params[3][:15] = 1.0  # alpha at the 0.999 clamp: rays that stop early
    az = torch.rand(rays, generator=g) * 0.4 - 0.2
    az[:8] += math.pi  # a few rays looking away: nothing hit
    el = torch.deg2rad(torch.rand(rays, generator=g) * 8 - 4)
    ray_bins = torch.randint(0, bins, (rays,), generator=g)
    cutoff = 4 + 8 * torch.rand(rays, generator=g)
    return [p.to(DEVICE) for p in params], az.to(DEVICE), el.to(DEVICE), ray_bins.to(DEVICE), cutoff.to(DEVICE)


def test_lidar_triton_equals_torch_compositor():
    base, az, el, ray_bins, cutoff = _lidar_scene()
    lidar = torch.eye(4, device=DEVICE)[None].repeat(2, 1, 1)
    results = {}
    for name in ("torch", "triton"):
        params = [t.clone().requires_grad_() for t in base]
        out = rasterize_lidar(*params, lidar, az, el, ray_bins=ray_bins, azimuth_resolution=math.radians(1.0),
                              elevation_resolution=math.radians(1.0), tile_size=4, ray_cutoff=cutoff,
                              compositor=name)  # fmt: skip
        loss = (out.features.square().sum() + (out.range * out.alpha).sum() + out.median_range.sum()
                + 3 * out.alpha_before_cutoff.sum())  # fmt: skip
        results[name] = out, torch.autograd.grad(loss, params)
    (ref, g_ref), (ours, g_ours) = results["torch"], results["triton"]
    assert (ref.alpha > 0.3).float().mean() > 0.2 and (ref.alpha > 0.99).any() and (ref.alpha == 0).any()
    assert ((ref.alpha_before_cutoff > 0) & (ref.alpha_before_cutoff < ref.alpha - 0.01)).any()  # cut-offs inside
    for name in ("features", "alpha", "range", "alpha_before_cutoff"):
        torch.testing.assert_close(getattr(ours, name), getattr(ref, name), atol=TOL, rtol=TOL)
    close = (ours.median_range - ref.median_range).abs() <= TOL * (1 + ref.median_range.abs())
    assert close.float().mean() > 0.99
    for x, y in zip(g_ours, g_ref):
        assert y.abs().max() > 0
        scale = y.abs().max().clamp_min(1.0)
        torch.testing.assert_close(x / scale, y / scale, atol=10 * TOL, rtol=0)


def test_lidar_triton_with_nothing_in_reach_is_empty_with_zero_gradients():
    base, az, el, ray_bins, cutoff = _lidar_scene(n=10, rays=20)
    params = [t.clone().requires_grad_() for t in base]
    lidar = torch.eye(4, device=DEVICE)[None].repeat(2, 1, 1)
    away = math.pi + 0.1 * (az - az.mean())  # every ray looks away from the Gaussians (behind, -x)
    # Not culled first, so that the kernels run on tiles whose lists are empty.
    out = rasterize_lidar(*params, lidar, away, el, ray_bins=ray_bins, tile_size=4, ray_cutoff=cutoff, cull=False,
                          compositor="triton")  # fmt: skip
    grads = torch.autograd.grad(out.alpha.sum() + out.alpha_before_cutoff.sum(), params, allow_unused=True)
    assert (out.alpha == 0).all() and (out.range == 0).all()
    assert all(g is None or (torch.isfinite(g).all() and (g == 0).all()) for g in grads)


def _long_list_plan(per_tile_basis: bool, seed=3):
    """A plan whose tiles hold 0, 1, a few chunks and many chunks of rows (lists longer than any
    kernel chunk), with padding lanes and a line-of-sight cut-off."""
    g = torch.Generator().manual_seed(seed)
    counts = torch.tensor([0, 1, 70, 260, 33])
    n_rows, slots, n_gauss = int(counts.sum()), 5, 90
    offsets = torch.cat([torch.zeros(1, dtype=torch.int64), torch.cumsum(counts, 0)])
    gid = torch.randint(0, n_gauss, (n_rows,), generator=g)
    ex, ey = torch.rand(len(counts), slots, generator=g) * 4 - 2, torch.rand(len(counts), slots, generator=g) * 4 - 2
    basis = monomial_basis(ex.double(), ey.double())  # [T, 6, S]
    if not per_tile_basis:
        basis = basis[0]
    conics = torch.stack([torch.rand(n_rows, generator=g) * 0.5 + 0.05, torch.rand(n_rows, generator=g) * 0.02,
                          torch.rand(n_rows, generator=g) * 0.5 + 0.05], 1)  # fmt: skip
    opac = torch.rand(n_rows, generator=g) * 0.6 + 0.05
    opac[::17] = 1.0  # the 0.999 clamp: lanes that stop early
    opac[71:331] *= 0.03  # tile 3: faint rows, its lanes composite all 260 (several kernel chunks)
    coeffs = quadratic_coefficients(torch.rand(n_rows, generator=g) * 4 - 2, torch.rand(n_rows, generator=g) * 4 - 2,
                                    conics, opac)  # fmt: skip
    valid = torch.ones(len(counts), slots)
    valid[2, 4] = valid[3, 0] = 0.0
    plan = CompositePlan(tile_offsets=offsets.to(DEVICE), gaussian_ids=gid.to(DEVICE), basis=basis.to(DEVICE),
                         slot_valid=valid.to(DEVICE), cutoff_depths=(torch.rand(len(counts), slots, generator=g) * 10).to(DEVICE),
                         gaussian_depths=(torch.rand(n_gauss, generator=g) * 10).to(DEVICE))  # fmt: skip
    return coeffs.to(DEVICE), torch.rand(n_gauss, 4, generator=g).to(DEVICE), plan


@pytest.mark.parametrize("per_tile_basis", [True, False])
def test_long_tile_lists_match_the_torch_compositor(per_tile_basis):
    from idsplat_ns.render.triton_composite import TritonTileComposite

    coeffs, feats, plan = _long_list_plan(per_tile_basis)
    outs = {}
    for name, fn in (("torch", TileComposite), ("triton", TritonTileComposite)):
        c, f = coeffs.clone().requires_grad_(), feats.clone().requires_grad_()
        out, crossing, before = fn.apply(c, f, plan)
        weights = torch.linspace(-1, 2, out.numel(), device=DEVICE).reshape(out.shape)
        loss = (out * weights).sum() + 3 * before.sum()
        outs[name] = (out, crossing, before, *torch.autograd.grad(loss, (c, f)))
    ref, ours = outs["torch"], outs["triton"]
    assert (ref[1] > 0).any() and (ref[2] > 0).any()
    assert (ref[1][3, 1:] > 64).all() and (ref[1][3, 1:] < 260).all()  # tile 3 crosses T = 0.5 after a chunk
    torch.testing.assert_close(ours[0], ref[0], atol=TOL, rtol=TOL)
    # The crossing row of valid lanes: any count >= the list length means "never crossed T = 0.5".
    counts = (plan.tile_offsets[1:] - plan.tile_offsets[:-1])[:, None]
    lanes = plan.slot_valid > 0
    assert torch.equal(ours[1].minimum(counts)[lanes], ref[1].minimum(counts)[lanes])
    torch.testing.assert_close(ours[2], ref[2], atol=TOL, rtol=TOL)
    for x, y in zip(ours[3:], ref[3:]):
        scale = y.abs().max().clamp_min(1.0)
        torch.testing.assert_close(x / scale, y / scale, atol=10 * TOL, rtol=0)


def test_auto_picks_compiled_on_cpu_and_triton_on_cuda():
    cpu = torch.zeros(3, 2)
    assert compositor.choose_compositor("auto", cpu) == "compiled"
    assert compositor.choose_compositor("torch", cpu) == "torch"
    if CUDA:
        assert compositor.choose_compositor("auto", cpu.cuda()) == "triton"
        assert compositor.choose_compositor("auto", cpu.cuda().double()) == "torch"  # the kernels are float32


def test_triton_option_errors_name_the_option(monkeypatch):
    with pytest.raises(IDSplatError, match="compositor='triton' runs on float32 CUDA tensors"):
        compositor.choose_compositor("triton", torch.zeros(3, 2, dtype=torch.float64))
    monkeypatch.setattr(compositor, "triton_installed", lambda: False)
    with pytest.raises(IDSplatError, match="compositor='triton' needs Triton"):
        compositor.choose_compositor("triton", torch.zeros(3, 2))
    assert compositor.choose_compositor("auto", torch.zeros(3, 2, dtype=torch.float16)) == "torch"


def test_triton_is_not_loaded_by_cpu_rendering():
    import subprocess
    import sys

    code = ("import sys, torch, idsplat_ns.render as r; "
            "r.rasterize_camera(torch.zeros(1, 3) + torch.tensor([0, 0, 3.0]), torch.tensor([[1.0, 0, 0, 0]]), "
            "torch.full((1, 3), 0.1), torch.ones(1) * 0.5, torch.ones(1, 2), torch.eye(4)[None], "
            "torch.tensor([[[10.0, 0, 4], [0, 10, 4], [0, 0, 1]]]), 8, 8, backend='torch'); print('triton' in sys.modules)")  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout.strip() == "False"


def test_lidar_compositor_option_is_checked_against_the_training_device():
    from idsplat_ns.runs.settings_checks import check_lidar_compositor

    with pytest.raises(IDSplatError, match="--pipeline.model.lidar.compositor triton needs a CUDA device"):
        check_lidar_compositor("triton", "cpu")
    with pytest.raises(IDSplatError, match="--pipeline.model.lidar.compositor compiled runs on the CPU"):
        check_lidar_compositor("compiled", "cuda")
    for ok in ("auto", "torch"):
        check_lidar_compositor(ok, "cpu")
        check_lidar_compositor(ok, "cuda")
