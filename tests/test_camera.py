import cv2
import numpy as np
import pytest

from idsplat_ns.data.camera import Intrinsics, pixel_rays, project_points, undistort_normalized, distort_normalized
from idsplat_ns.data.geometry import make_pose, rot_z


def _camera():
    # A camera 2 m up looking along world +x (OpenCV axes: z forward = world x, x right = world -y, y down = world -z).
    R = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], dtype=np.float64)
    return make_pose(R, np.array([0.0, 0.0, 2.0]))


def test_pinhole_closed_form():
    intr = Intrinsics(fx=500, fy=400, cx=320, cy=240, width=640, height=480)
    pts = np.array([[10.0, 0.0, 2.0], [10.0, 1.0, 2.0], [5.0, 0.0, 3.0], [-5.0, 0.0, 2.0]])
    proj = project_points(pts, _camera(), intr)
    # Closed form: u = cx + fx * (-y) / x, v = cy + fy * (2 - z) / x for a camera at height 2 looking along +x.
    np.testing.assert_allclose(proj.uv[:3], [[320, 240], [320 - 500 * 0.1, 240], [320, 240 - 400 * 0.2]], atol=1e-9)
    np.testing.assert_allclose(proj.depth[:3], [10, 10, 5])
    assert proj.valid.tolist() == [True, True, True, False]  # behind the camera


def test_distortion_matches_opencv_and_inverts():
    rng = np.random.default_rng(0)
    dist = (-0.32, 0.11, 0.001, -0.0005, -0.02)
    intr = Intrinsics(fx=2000, fy=2000, cx=960, cy=640, width=1920, height=1280, distortion=dist)
    c2w = make_pose(rot_z(0.3) @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0.0]]), np.array([1e4, -2e3, 2.0]))
    pts_cam = np.stack([rng.uniform(-4, 4, 100), rng.uniform(-2, 2, 100), rng.uniform(5, 40, 100)], 1)
    pts_world = pts_cam @ c2w[:3, :3].T + c2w[:3, 3]
    proj = project_points(pts_world, c2w, intr)
    ref, _ = cv2.projectPoints(pts_cam, np.zeros(3), np.zeros(3), intr.K, np.array(dist))
    np.testing.assert_allclose(proj.uv, ref[:, 0], atol=1e-6)
    xy = rng.uniform(-0.5, 0.5, (50, 2))
    np.testing.assert_allclose(undistort_normalized(distort_normalized(xy, dist), dist), xy, atol=1e-9)
    # pixel_rays is the inverse of projection.
    o, d = pixel_rays(proj.uv, c2w, intr)
    back = project_points(o + d * 10.0, c2w, intr)
    np.testing.assert_allclose(back.uv, proj.uv, atol=1e-5)


def test_scaled_intrinsics():
    intr = Intrinsics(fx=1000, fy=1000, cx=960, cy=540, width=1920, height=1080).scaled(0.25)
    assert (intr.width, intr.height) == (480, 270)
    assert intr.fx == pytest.approx(250) and intr.cx == pytest.approx(240)


def test_points_beyond_the_lens_monotonic_range_are_rejected():
    # Waymo-like lens: k2 < 0 makes the radial polynomial fold back at r^2 ~ 0.8.
    intr = Intrinsics(fx=2000, fy=2000, cx=960, cy=640, width=1920, height=1280, distortion=(0.04, -0.33, 0.0, 0.0, 0.0))
    s_max = intr.max_valid_radius2
    r = np.sqrt(np.linspace(0.01, s_max * 0.999, 200))
    rd = r * (1 + 0.04 * r**2 - 0.33 * r**4)
    assert np.all(np.diff(rd) > 0)  # monotonic up to the limit
    assert 1 + 3 * 0.04 * s_max + 5 * -0.33 * s_max**2 == pytest.approx(0.0, abs=1e-9)
    c2w = np.eye(4)
    far_side = np.array([[1.4, 0.0, 1.0]])  # r^2 = 1.96: folds back to about x = 0.17, inside the image
    assert not project_points(far_side, c2w, intr).valid[0]
    assert project_points(np.array([[0.3, 0.0, 1.0]]), c2w, intr).valid[0]
    assert Intrinsics(fx=1, fy=1, cx=0, cy=0, width=1, height=1).max_valid_radius2 == float("inf")


def test_undistorted_view_matches_pinhole_projection():
    from idsplat_ns.data.camera import CameraImage
    from idsplat_ns.data.images import load_rgb, undistorted_view

    dist = (-0.3, 0.08, 0.0, 0.0, 0.0)
    lens = Intrinsics(fx=100, fy=100, cx=80, cy=60, width=160, height=120, distortion=dist)
    # A distorted image of a single bright world point: draw it where the full lens model puts it.
    point = np.array([[0.45, -0.3, 1.0]])  # camera frame = world frame here
    uv_d = project_points(point, np.eye(4), lens).uv[0]
    pixels = np.zeros((120, 160, 3), np.uint8)
    r, c = int(round(uv_d[1])), int(round(uv_d[0]))
    pixels[r - 1 : r + 2, c - 1 : c + 2] = 255
    image = CameraImage(camera="cam", frame_index=0, time=0.0, raw_timestamp=0.0, camera_to_world=np.eye(4), intrinsics=lens, image=pixels)
    view = undistorted_view(image)
    assert not view.intrinsics.has_distortion
    out = load_rgb(view).astype(float)[..., 0]
    ys, xs = np.nonzero(out > 0.5 * out.max())
    uv_pinhole = project_points(point, np.eye(4), view.intrinsics).uv[0]
    assert abs(xs.mean() - uv_pinhole[0]) < 1.0 and abs(ys.mean() - uv_pinhole[1]) < 1.0
    assert np.hypot(*(uv_pinhole - uv_d)) > 3  # the lens really moved it (4.4 px here)
