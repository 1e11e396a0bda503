"""Rolling shutter in the camera rasterizer: closed forms for moving points and moving cameras,
the global-shutter path unchanged bit for bit, and the tile rasterizer equal to the dense reference."""

import math

import pytest
import torch

from idsplat_ns.data.camera import RollingShutter
from idsplat_ns.data.rolling_shutter import time_plane
from idsplat_ns.render import CameraMotion, ShutterTiming, project_gaussians, rasterize_camera, rasterize_dense

W, H = 64, 48
FX = FY = 50.0
CX, CY = 32.0, 24.0
K = torch.tensor([[[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]]], dtype=torch.float64)


def _timing(readout, direction, width=W, height=H, full=None):
    full_w, full_h = full if full is not None else (width, height)
    return ShutterTiming.from_planes([time_plane(RollingShutter(readout, direction), width, height, full_w, full_h)])


def _motion(timing, lin=(0.0, 0.0, 0.0), ang=(0.0, 0.0, 0.0), velocities=None):
    return CameraMotion(timing, torch.tensor([lin], dtype=torch.float64), torch.tensor([ang], dtype=torch.float64),
                        velocities)


def _point(x, y, z, dtype=torch.float64):
    """One small round Gaussian (1 cm) at camera-frame (x, y, z) with the camera at the origin."""
    means = torch.tensor([[x, y, z]], dtype=dtype)
    quats = torch.tensor([[1.0, 0, 0, 0]], dtype=dtype)
    scales = torch.full((1, 3), 0.01, dtype=dtype)
    return means, quats, scales


def test_time_plane_is_the_documented_line_times():
    # Line centres i + 0.5: the first at -R/2, the last at +R/2, the centre line at 0, per direction.
    R = 0.04
    t0, du, dv = time_plane(RollingShutter(R, "top_to_bottom"), W, H)
    assert du == 0 and math.isclose(t0 + dv * 0.5, -R / 2) and math.isclose(t0 + dv * (H - 0.5), R / 2)
    t0, du, dv = time_plane(RollingShutter(R, "right_to_left"), W, H)
    assert dv == 0 and math.isclose(t0 + du * 0.5, R / 2) and math.isclose(t0 + du * (W - 0.5), -R / 2)
    # A half-size render: the same physical line (full-res row 2k+1 centre = half-res row k centre) keeps its time.
    full = time_plane(RollingShutter(R, "bottom_to_top"), W, H)
    half = time_plane(RollingShutter(R, "bottom_to_top"), W // 2, H // 2, W, H)
    for k in range(H // 2):
        assert math.isclose(half[0] + half[2] * (k + 0.5), full[0] + full[2] * (2 * k + 1), abs_tol=1e-15)
    assert time_plane(RollingShutter(0.0, "top_to_bottom"), W, H) == (0.0, 0.0, 0.0)
    assert time_plane(RollingShutter(R, "global"), W, H) == (0.0, 0.0, 0.0)
    assert time_plane(None, W, H) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("direction", ["top_to_bottom", "bottom_to_top"])
def test_point_moving_sideways_lands_where_its_row_was_exposed(direction):
    # A point moving along x keeps its row; it is seen where it was when that row was exposed.
    R, vx = 0.05, 12.0
    x, y, z = -0.3, 1.5, 6.0
    means, quats, scales = _point(x, y, z)
    motion = _motion(_timing(R, direction), velocities=torch.tensor([[vx, 0.0, 0.0]], dtype=torch.float64))
    p = project_gaussians(means, quats, scales, torch.eye(4, dtype=torch.float64)[None], K, W, H, motion=motion)
    row = FY * y / z + CY
    sign = 1 if direction == "top_to_bottom" else -1
    tau = sign * (row - H / 2) / (H - 1) * R
    expect = torch.tensor([FX * (x + vx * tau) / z + CX, row], dtype=torch.float64)
    torch.testing.assert_close(p.means2d[0, 0], expect, atol=1e-9, rtol=0)
    assert abs(p.means2d[0, 0, 0] - (FX * x / z + CX)) > 0.5  # the effect is visible (1.3 px)

    # The rendered blob's alpha centroid is there too (float32 image, the renderer's own path; a
    # 10 cm Gaussian, about 1 px wide, so that sampling at pixel centres does not bias the centroid).
    out = rasterize_camera(means.float(), quats.float(), 10 * scales.float(), torch.tensor([0.9]), torch.ones(1, 1),
                           torch.eye(4)[None], K.float(), W, H, backend="torch",
                           motion=_motion(_timing(R, direction), velocities=torch.tensor([[vx, 0.0, 0.0]])))
    a = out.alpha[0, ..., 0].double()
    ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    centroid = torch.stack([(a * xs).sum() / a.sum(), (a * ys).sum() / a.sum()])
    torch.testing.assert_close(centroid, expect, atol=2e-3, rtol=0)


def test_camera_moving_along_the_readout_solves_for_its_own_column():
    # Left-to-right readout, camera translating along +x at s m/s: a static point's column u
    # satisfies u = fx (X - s tau(u)) / Z + cx with tau linear in u; a linear equation in u.
    R, s = 0.03, 15.0
    X, Y, Z = 0.4, -0.2, 3.0
    means, quats, scales = _point(X, Y, Z)
    t0, du, _ = time_plane(RollingShutter(R, "left_to_right"), W, H)
    motion = _motion(_timing(R, "left_to_right"), lin=(s, 0.0, 0.0))
    p = project_gaussians(means, quats, scales, torch.eye(4, dtype=torch.float64)[None], K, W, H, motion=motion)
    u = (FX * (X - s * t0) / Z + CX) / (1 + FX * s * du / Z)
    torch.testing.assert_close(p.means2d[0, 0], torch.tensor([u, FY * Y / Z + CY], dtype=torch.float64), atol=1e-9, rtol=0)
    # The solution is self-consistent: tau at the landing column moves the point there.
    tau = t0 + du * u
    assert math.isclose(u, FX * (X - s * tau) / Z + CX, abs_tol=1e-9)


def test_turning_camera_first_order_matches_the_exact_rotation():
    # A camera yawing at w rad/s about its y axis (world = camera frame at t): a point straight
    # ahead at row r is seen at u = cx - fx tan(w tau(r)) exactly; the model is first order in w tau.
    R, w = 0.04, 0.8
    Y, Z = 1.2, 8.0
    means, quats, scales = _point(0.0, Y, Z)
    motion = _motion(_timing(R, "top_to_bottom"), ang=(0.0, w, 0.0))
    p = project_gaussians(means, quats, scales, torch.eye(4, dtype=torch.float64)[None], K, W, H, motion=motion)
    row = FY * Y / Z + CY
    tau = (row - H / 2) / (H - 1) * R
    assert abs(w * tau) > 2e-3
    exact_u = CX - FX * math.tan(w * tau)  # the rotation moves x_c = -Z sin(w tau), z_c = Z cos(w tau)
    assert abs(float(p.means2d[0, 0, 0]) - exact_u) < FX * (w * tau) ** 2  # second-order residual
    assert abs(float(p.means2d[0, 0, 0]) - CX) > 0.1


def _scene(n=200, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.0, 0.8, 0.5]) + torch.tensor([0, 0, 4.0])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.2 + 0.01
    opac = torch.rand(n, generator=g) * 0.98 + 0.01
    feats = torch.rand(n, 4, generator=g)
    vel = torch.randn(n, 3, generator=g) * 5.0
    viewmats = torch.eye(4)[None].repeat(2, 1, 1)
    viewmats[1, 0, 3] = 0.3
    Ks = torch.tensor([[40.0, 0, 18], [0, 40, 14], [0, 0, 1]])[None].repeat(2, 1, 1)
    return means, quats, scales, opac, feats, vel, viewmats, Ks


def _two_camera_motion(vel, w, h):
    timing = ShutterTiming.from_planes([time_plane(RollingShutter(0.04, "top_to_bottom"), w, h),
                                        time_plane(RollingShutter(0.03, "right_to_left"), w, h)])
    return CameraMotion(timing, torch.tensor([[3.0, 0.0, 8.0], [0.0, 1.0, -2.0]]),
                        torch.tensor([[0.0, 0.3, 0.0], [0.1, 0.0, 0.2]]), vel)


def test_global_shutter_renders_bit_identically():
    means, quats, scales, opac, feats, vel, vm, Ks = _scene()
    w, h = 37, 29
    plain = rasterize_camera(means, quats, scales, opac, feats, vm, Ks, w, h, backend="torch")
    for timing in (ShutterTiming.from_planes([time_plane(RollingShutter(0.0, "top_to_bottom"), w, h)] * 2),
                   ShutterTiming.from_planes([time_plane(RollingShutter(0.04, "global"), w, h)] * 2)):
        motion = CameraMotion(timing, torch.ones(2, 3), torch.ones(2, 3), vel)
        out = rasterize_camera(means, quats, scales, opac, feats, vm, Ks, w, h, backend="torch", motion=motion)
        for name in ("features", "alpha", "depth", "median_depth", "means2d", "radii"):
            assert torch.equal(getattr(out, name), getattr(plain, name)), name
    # A real rolling shutter does change the image (the test above could not fail otherwise).
    moved = rasterize_camera(means, quats, scales, opac, feats, vm, Ks, w, h, backend="torch",
                             motion=_two_camera_motion(vel, w, h))
    assert (moved.features - plain.features).abs().max() > 0.05


def test_rolling_shutter_tile_rasterizer_equals_dense_reference():
    # Both consume the same shifted projection: images and gradients (velocities included) agree.
    means, quats, scales, opac, feats, vel, vm, Ks = _scene(seed=1)
    w, h = 37, 29
    params = [t.clone().requires_grad_() for t in (means, quats, scales, opac, feats, vel)]
    out = rasterize_camera(*params[:5], vm, Ks, w, h, backend="torch", tile_size=8,
                           motion=_two_camera_motion(params[5], w, h))
    p = project_gaussians(params[0], params[1], params[2], vm, Ks, w, h, motion=_two_camera_motion(params[5], w, h))
    f, a, dsum, med, _ = rasterize_dense(p.means2d, p.conics, p.depths, p.radii, params[3], params[4], w, h)
    torch.testing.assert_close(out.features, f, atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(out.alpha, a, atol=2e-6, rtol=1e-5)
    torch.testing.assert_close(out.median_depth, med, atol=1e-6, rtol=1e-6)
    ours = out.features.square().sum() + 3 * out.alpha.sum() + out.depth.sum()
    ref = f.square().sum() + 3 * a.sum() + torch.where(a > 0, dsum / a.clamp_min(1e-30), 0.0).sum()
    grads = torch.autograd.grad(ours, params)
    for g_ours, g_ref in zip(grads, torch.autograd.grad(ref, params)):
        torch.testing.assert_close(g_ours, g_ref, atol=1e-4, rtol=1e-4)
    assert grads[5].abs().max() > 0  # the velocities get a gradient


def test_velocity_gradient_matches_finite_differences():
    # float64 gradcheck through the shift (velocities and camera velocities).
    means, quats, scales = _point(0.2, -0.1, 3.0)
    opac, feats = torch.tensor([0.7], dtype=torch.float64), torch.tensor([[1.0]], dtype=torch.float64)
    timing = _timing(0.05, "top_to_bottom", 16, 12)
    Ks = torch.tensor([[[12.0, 0, 8], [0, 12, 6], [0, 0, 1]]], dtype=torch.float64)
    scales = scales * 20

    def fn(vel, lin, ang):
        m = CameraMotion(timing, lin, ang, vel)
        return rasterize_camera(means, quats, scales, opac, feats, torch.eye(4, dtype=torch.float64)[None], Ks, 16, 12,
                                backend="torch", tile_size=4, motion=m).features

    inputs = [torch.tensor([[4.0, -1.0, 2.0]], dtype=torch.float64, requires_grad=True),
              torch.tensor([[1.0, 0.5, 3.0]], dtype=torch.float64, requires_grad=True),
              torch.tensor([[0.1, 0.2, -0.1]], dtype=torch.float64, requires_grad=True)]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)
