"""Projection: parity with gsplat's pure-torch reference on real data, and guarded extremes."""

from pathlib import Path

import numpy as np
import pytest
import torch

from idsplat_ns.render import project_gaussians, quat_to_rotmat

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
GARDEN = DATA / "gsplat" / "test_garden.npz"


def _garden(n: int | None = None):
    if not GARDEN.exists():
        pytest.skip(f"{GARDEN} not found (shared test data)")
    d = np.load(GARDEN)
    means = torch.from_numpy(d["means3d"]).float()
    if n is not None:
        means = means[:: max(1, means.shape[0] // n)][:n]
    g = torch.Generator().manual_seed(0)
    quats = torch.randn(means.shape[0], 4, generator=g)
    scales = torch.rand(means.shape[0], 3, generator=g) * 0.05 + 1e-3
    return (means, quats, scales, torch.from_numpy(d["viewmats"]).float(),
            torch.from_numpy(d["Ks"]).float(), int(d["width"]), int(d["height"]))  # fmt: skip


def test_projection_matches_gsplat_reference_on_garden():
    torch_impl = pytest.importorskip("gsplat.cuda._torch_impl")
    means, quats, scales, viewmats, Ks, width, height = _garden()
    covars, _ = torch_impl._quat_scale_to_covar_preci(quats, scales, compute_preci=False)
    radii, means2d, depths, conics, comp = torch_impl._fully_fused_projection(
        means, covars, viewmats, Ks, width, height, calc_compensations=True
    )
    ours = project_gaussians(means, quats, scales, viewmats, Ks, width, height, calc_compensations=True)
    assert ours.radii.dtype == torch.int32 and ours.radii.shape == radii.shape
    assert torch.equal(ours.radii, radii)
    valid = radii > 0
    assert valid.sum() > 100_000  # the test exercises many visible Gaussians
    torch.testing.assert_close(ours.means2d[valid], means2d[valid], rtol=1e-5, atol=1e-3)
    torch.testing.assert_close(ours.depths[valid], depths[valid], rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(ours.conics[valid], conics[valid], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(ours.compensations[valid], comp[valid], rtol=1e-4, atol=1e-4)


def test_projection_gradients_match_gsplat_reference():
    torch_impl = pytest.importorskip("gsplat.cuda._torch_impl")
    means, quats, scales, viewmats, Ks, width, height = _garden(2000)
    params = [t.double().requires_grad_() for t in (means, quats, scales, viewmats)]
    Ks = Ks.double()

    def loss(m2d, dep, con, valid):
        w = valid.to(m2d.dtype)
        return ((m2d.sin().sum(-1) + dep.cos() + con.sum(-1)) * w).sum()

    ours = project_gaussians(*params, Ks, width, height)
    g_ours = torch.autograd.grad(loss(ours.means2d, ours.depths, ours.conics, ours.radii > 0), params)
    covars, _ = torch_impl._quat_scale_to_covar_preci(params[1], params[2], compute_preci=False)
    radii, m2d, dep, con, _ = torch_impl._fully_fused_projection(params[0], covars, params[3], Ks, width, height)
    g_ref = torch.autograd.grad(loss(m2d, dep, con, radii > 0), params)
    for a, b in zip(g_ours, g_ref):
        torch.testing.assert_close(a, b, rtol=1e-7, atol=1e-9)


def test_rotation_is_orthonormal_and_zero_quaternion_is_identity():
    q = torch.tensor([[0.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0], [0.3, -0.2, 0.9, 0.1]])
    rot = quat_to_rotmat(q)
    torch.testing.assert_close(rot[0], torch.eye(3))
    torch.testing.assert_close(rot[1], torch.eye(3))
    torch.testing.assert_close(rot[2] @ rot[2].T, torch.eye(3), atol=1e-6, rtol=0)
    assert torch.det(rot[2]).item() == pytest.approx(1.0, abs=1e-6)


def test_projection_culls_behind_near_and_far_without_nan():
    means = torch.tensor([[0.0, 0, -5], [0.0, 0, 0], [0.0, 0, 0.005], [0.0, 0, 2e10], [0.0, 0, 5]])
    means.requires_grad_()
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(5, 1)
    scales = torch.full((5, 3), 0.1)
    K = torch.tensor([[[100.0, 0, 50], [0, 100, 40], [0, 0, 1]]])
    proj = project_gaussians(means, quats, scales, torch.eye(4)[None], K, 100, 80)
    assert proj.radii[0].tolist()[:4] == [0, 0, 0, 0] and proj.radii[0, 4] > 0
    # A Gaussian at the centre of a 100x80 image at 5 m projects to the principal point.
    torch.testing.assert_close(proj.means2d[0, 4], torch.tensor([50.0, 40.0]))
    total = proj.means2d.sum() + proj.conics.sum() + proj.depths.sum()
    assert torch.isfinite(total)
    (grad,) = torch.autograd.grad(total, means)
    assert torch.isfinite(grad).all()
