import pytest
import torch

from idsplat_ns.eval.image_metrics import psnr, ssim


def test_psnr_closed_form_and_mask():
    gt = torch.zeros(4, 5, 3)
    pred = gt + 0.1
    assert float(psnr(pred, gt)) == pytest.approx(20.0, abs=1e-4)
    pred2 = gt.clone()
    pred2[:2] = 0.01  # error only in the top half
    mask = torch.zeros(4, 5, dtype=torch.bool)
    mask[:2] = True
    assert float(psnr(pred2, gt, mask)) == pytest.approx(40.0, abs=1e-3)
    assert float(psnr(pred2, gt, ~mask)) == pytest.approx(100.0, abs=1e-3)  # clamped perfect score


def test_ssim_closed_forms_and_an_interior_pixel_by_hand():
    import numpy as np

    from idsplat_ns.eval.image_metrics import ssim_map

    c1, c2 = 0.01**2, 0.03**2
    # Constant images: no variance, SSIM = (2 ab + c1) / (a^2 + b^2 + c1) everywhere.
    a, b = torch.full((1, 3, 20, 24), 0.3), torch.full((1, 3, 20, 24), 0.5)
    assert float(ssim(a, b)) == pytest.approx((2 * 0.15 + c1) / (0.09 + 0.25 + c1), abs=1e-5)
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(1, 1, 30, 30, generator=gen)
    y = (x + 0.1 * torch.randn(1, 1, 30, 30, generator=gen)).clamp(0, 1)
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)
    # One pixel far from the border, from the definition: Gaussian-weighted means and (co)variances.
    k = np.arange(11) - 5.0
    g = np.exp(-(k**2) / (2 * 1.5**2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    px, py = x[0, 0, 10:21, 12:23].double().numpy(), y[0, 0, 10:21, 12:23].double().numpy()
    mx, my = (w * px).sum(), (w * py).sum()
    vx, vy, cxy = (w * px * px).sum() - mx**2, (w * py * py).sum() - my**2, (w * px * py).sum() - mx * my
    expected = (2 * mx * my + c1) * (2 * cxy + c2) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
    assert float(ssim_map(x, y)[0, 0, 15, 17]) == pytest.approx(expected, abs=1e-5)


def test_lpips_matches_reference_package(tmp_path):
    lpips_pkg = pytest.importorskip("lpips")
    from idsplat_ns.eval.lpips import LPIPS

    torch.manual_seed(0)
    # Reference with a random backbone (pnet_rand: no download) and the packaged calibration layers.
    ref = lpips_pkg.LPIPS(pretrained=True, net="alex", pnet_rand=True, verbose=False).eval()
    state = {}
    for key, value in ref.net.state_dict().items():  # net.sliceK.<original index>.weight
        _, idx, kind = key.split(".")
        state[f"features.{idx}.{kind}"] = value
    backbone = tmp_path / "alexnet.pth"
    torch.save(state, backbone)
    ours = LPIPS.from_files(backbone, net="alex")
    gen = torch.Generator().manual_seed(1)
    a = torch.rand(64, 64, 3, generator=gen)
    b = (a + 0.2 * torch.rand(64, 64, 3, generator=gen)).clamp(0, 1)
    expected = ref(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None], normalize=True).item()
    assert float(ours(a, b)) == pytest.approx(expected, rel=1e-5)
    assert float(ours(a, a)) == pytest.approx(0.0, abs=1e-7)


def test_lpips_missing_backbone_is_one_line(tmp_path):
    from idsplat_ns.errors import IDSplatError
    from idsplat_ns.eval.lpips import LPIPS

    with pytest.raises(IDSplatError, match="LPIPS backbone weights not found"):
        LPIPS.from_files(tmp_path / "nope.pth")


def test_colour_aligned_is_the_least_squares_affine_map_numpys_lstsq_finds() -> None:
    """Against numpy's least squares (an independent solver), a render that is an affine colour
    map of the image is mapped back onto it, and a flat render stays finite."""
    import numpy as np

    from idsplat_ns.eval.image_metrics import colour_aligned, psnr

    g = torch.Generator().manual_seed(0)
    gt = torch.rand(24, 32, 3, generator=g)
    pred = (torch.rand(24, 32, 3, generator=g) * 0.5 + gt * 0.5).clamp(0, 1)
    X = np.concatenate([pred.reshape(-1, 3).double().numpy(), np.ones((24 * 32, 1))], axis=1)
    coefficients, *_ = np.linalg.lstsq(X, gt.reshape(-1, 3).double().numpy(), rcond=None)
    expected = np.clip(X @ coefficients, 0, 1).reshape(24, 32, 3)
    assert np.allclose(colour_aligned(pred, gt).double().numpy(), expected, atol=1e-5)
    drifted = gt * torch.tensor([0.7, 0.8, 1.1]) * 0.8 + 0.05  # a gain and an offset per channel
    assert float(psnr(drifted.clamp(0, 1), gt)) < 25 and float(psnr(colour_aligned(drifted, gt), gt)) > 60
    flat = torch.full((8, 8, 3), 0.5)
    assert torch.isfinite(colour_aligned(flat, gt[:8, :8])).all()
