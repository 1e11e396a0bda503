"""Camera pose refinement (issue 45): the corrections are exact rigid motions in the camera frame
(against scipy), identity at the start; a camera turned by a degree is found again from its images
alone through the differentiable rasterizer, and so is a per-image pose error that wanders over
the drive, at the training images and, interpolated, between them."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from idsplat_ns.model.camera_refinement import ImagePoseCorrection, RigCorrection
from idsplat_ns.render import rasterize_camera


def test_the_correction_is_a_rigid_motion_in_the_camera_frame() -> None:
    rig = RigCorrection(2)
    viewmat = torch.eye(4)
    viewmat[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    assert torch.equal(rig(viewmat, 0), viewmat)  # identity at the start
    assert rig(viewmat, 5) is viewmat  # not a camera of the rig (the viewer's)
    with torch.no_grad():
        rig.rotation[1] = torch.tensor([0.01, -0.02, 0.005])
        rig.translation[1] = torch.tensor([0.1, 0.0, -0.05])
    E = np.eye(4)
    E[:3, :3] = Rotation.from_rotvec([0.01, -0.02, 0.005]).as_matrix()
    E[:3, 3] = [0.1, 0.0, -0.05]
    assert np.allclose(rig(viewmat, 1).detach().numpy(), E @ viewmat.numpy(), atol=1e-6)
    assert abs(rig.summary()[1][0] - math.degrees(np.linalg.norm([0.01, -0.02, 0.005]))) < 1e-4
    assert abs(rig.summary()[1][1] - np.linalg.norm([0.1, 0.0, -0.05])) < 1e-6
    # The prior counts corrections in units of their expected size: 1 degree and 5 cm.
    with torch.no_grad():
        rig.rotation.zero_()
        rig.translation.zero_()
        rig.rotation[0, 2] = math.radians(1.0)
        rig.translation[1, 0] = 0.05
    assert float(rig.prior(1.0, 0.05)) == np.float32(1.0).item()


def _scene_renderer():
    """A render function ``view [4, 4] -> [64, 96, 3]`` of a fixed scene of 400 Gaussians ahead."""
    torch.manual_seed(0)
    n = 400
    means = torch.stack([torch.rand(n) * 16 - 8, torch.rand(n) * 8 - 4, torch.rand(n) * 20 + 10], -1)  # in front
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
    scales = torch.full((n, 3), 0.25)
    opacities = torch.full((n,), 0.9)
    colours = torch.rand(n, 3)
    K = torch.tensor([[80.0, 0, 48], [0, 80.0, 32], [0, 0, 1]])

    def render(view):
        return rasterize_camera(means, quats, scales, opacities, colours, view[None], K[None], 96, 64,
                                backend="torch").features[0]

    return render


def _turn(axis: str, degrees: float) -> torch.Tensor:
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler(axis, degrees, degrees=True).as_matrix()
    return torch.as_tensor(turn, dtype=torch.float32)


def _angle_deg(a: torch.Tensor, b: torch.Tensor) -> float:
    """The rotation angle between the rotations of two views."""
    rel = (a @ torch.linalg.inv(b)).detach().numpy()[:3, :3].astype(np.float64)
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(rel).as_rotvec())))


def test_a_turned_camera_is_found_again_from_its_images() -> None:
    """A scene of Gaussians seen by a camera whose calibration says it looks 1 degree to the left
    of where it does: fitting only the correction to the true images recovers the turn."""
    render = _scene_renderer()
    true_view = torch.eye(4)
    told_view = _turn("y", 1.0) @ true_view  # the calibration's (wrong) view

    target = render(true_view).detach()
    rig = RigCorrection(1)
    opt = torch.optim.Adam(rig.parameters(), lr=2e-3)
    before = float((render(rig(told_view, 0)) - target).abs().mean())
    for _ in range(150):
        opt.zero_grad()
        loss = (render(rig(told_view, 0)) - target).abs().mean()
        loss.backward()
        opt.step()
    after = float(loss)
    residual = _angle_deg(rig(told_view, 0), true_view)
    print(f"L1 {before:.4f} -> {after:.4f}; turn left after fitting {residual:.3f} deg (was 1 deg)")
    assert after < 0.5 * before
    assert residual < 0.2


def test_the_per_image_correction_is_its_images_and_interpolated_between() -> None:
    poses = ImagePoseCorrection([np.array([0.0, 0.2]), np.array([]), np.array([0.1])])
    viewmat = torch.eye(4)
    viewmat[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    assert torch.equal(poses(viewmat, 0, 0.1), viewmat)  # identity at the start
    assert poses(viewmat, 1, 0.1) is viewmat and poses(viewmat, 0, None) is viewmat and poses(viewmat, 4, 0.0) is viewmat
    w0, w1 = np.array([0.01, -0.02, 0.005]), np.array([-0.01, 0.0, 0.015])
    t0, t1 = np.array([0.1, 0.0, -0.05]), np.array([0.0, 0.2, 0.05])
    with torch.no_grad():
        poses.rotation[:2] = torch.tensor(np.stack([w0, w1]), dtype=torch.float32)
        poses.translation[:2] = torch.tensor(np.stack([t0, t1]), dtype=torch.float32)

    def expected(w, t):
        E = np.eye(4)
        E[:3, :3] = Rotation.from_rotvec(w).as_matrix()
        E[:3, 3] = t
        return E @ viewmat.numpy()

    assert np.allclose(poses(viewmat, 0, 0.2).detach().numpy(), expected(w1, t1), atol=1e-6)  # a training image
    between = poses(viewmat, 0, 0.05)  # a quarter of the way to the second knot
    assert np.allclose(between.detach().numpy(), expected(0.75 * w0 + 0.25 * w1, 0.75 * t0 + 0.25 * t1), atol=1e-6)
    between.sum().backward()  # gradients reach the two neighbours only
    assert (poses.rotation.grad.abs().sum(-1) > 0).tolist() == [True, True, False]
    assert np.allclose(poses(viewmat, 0, 9.0).detach().numpy(), expected(w1, t1), atol=1e-6)  # clamped at the end
    again = ImagePoseCorrection.like({f"p.{k}": v for k, v in poses.state_dict().items()}, "p.")
    again.load_state_dict(poses.state_dict())
    assert torch.equal(again(viewmat, 2, 0.1), poses(viewmat, 2, 0.1))
    median_deg = np.degrees(np.median([np.linalg.norm(w0), np.linalg.norm(w1)]))
    assert poses.summary()[0][0] == pytest.approx(median_deg, rel=1e-5) and poses.summary()[1] == (0.0, 0.0)


def test_a_wandering_pose_error_is_found_at_training_images_and_between() -> None:
    """Five frames of one camera whose written poses turn by a slowly wandering error (up to 0.8
    degrees); fitting the per-image corrections on frames 0, 2 and 4 finds their errors again and
    the interpolated corrections shrink the held-out frames' errors."""
    render = _scene_renderer()
    times = np.arange(5) * 0.1
    errors = 0.8 * np.sin(2 * np.pi * times / 0.8)  # degrees, about the vertical axis
    true_view = torch.eye(4)
    told = [_turn("y", float(e)) @ true_view for e in errors]
    targets = [render(true_view).detach()] * 5
    train = [0, 2, 4]
    poses = ImagePoseCorrection([times[train]])
    opt = torch.optim.Adam(poses.parameters(), lr=2e-3)
    for _ in range(120):
        opt.zero_grad()
        loss = sum((render(poses(told[i], 0, float(times[i]))) - targets[i]).abs().mean() for i in train)
        loss.backward()
        opt.step()
    left = [_angle_deg(poses(told[i], 0, float(times[i])), true_view) for i in range(5)]
    print("error left (deg):", np.round(left, 3), "of", np.round(np.abs(errors), 3))
    assert max(left[i] for i in train) < 0.15
    for i in (1, 3):  # held out: linear interpolation of a sine between two training frames
        assert left[i] < 0.5 * abs(errors[i])


def test_the_generator_writes_a_miscalibrated_camera(tiny_street, tmp_path) -> None:
    """``idsplat-synth --calibration-error-deg 1 0.5``: the front-left camera's written pose is turned
    by the error (1.118 degrees in all), its images are those of the true pose, other cameras as before."""
    import filecmp
    import json

    from idsplat_ns.data.synthetic import generate_sequence
    from idsplat_ns.data.synthetic.cli import config_from_args
    from idsplat_ns.data.synthetic.config import config_to_dict, get_preset

    assert "calibration_error_deg" not in config_to_dict(get_preset("tiny"))["cameras"]  # old streets stay cache hits
    config = config_from_args("tiny", None, None, calibration_error_deg=(1.0, 0.5))
    assert config.name == "tiny_cal1x0.5"
    wrong = generate_sequence(tmp_path, config, seed=0, progress=False)

    def headings(street, cam):
        return [Rotation.from_quat([p["heading"][k] for k in "xyzw"])
                for p in json.loads((street / "camera" / cam / "poses.json").read_text())]

    turned = [np.degrees((a.inv() * b).magnitude()) for a, b in
              zip(headings(tiny_street, "front_left_camera"), headings(wrong, "front_left_camera"))]
    assert np.allclose(turned, np.degrees(np.hypot(np.radians(1.0), np.radians(0.5))), atol=1e-3)
    assert (tiny_street / "camera/front_camera/poses.json").read_text() == (wrong / "camera/front_camera/poses.json").read_text()
    assert filecmp.cmp(tiny_street / "camera/front_left_camera/03.jpg", wrong / "camera/front_left_camera/03.jpg", shallow=False)


def test_the_generator_writes_wandering_camera_poses(tiny_street, tmp_path) -> None:
    """``idsplat-synth --pose-noise 0.5 0.1``: every camera's written pose of a frame carries the
    same ego-frame error (so the rig's relative poses are unchanged), the images and the lidar's
    poses are those of the exact street."""
    import filecmp
    import json

    from idsplat_ns.data.synthetic import generate_sequence
    from idsplat_ns.data.synthetic.cli import config_from_args
    from idsplat_ns.data.synthetic.config import config_to_dict, get_preset

    assert "pose_noise" not in config_to_dict(get_preset("tiny"))["cameras"]  # old streets stay cache hits
    config = config_from_args("tiny", None, None, pose_noise=(0.5, 0.1))
    assert config.name == "tiny_pn0.5x0.1"
    noisy = generate_sequence(tmp_path, config, seed=0, progress=False)

    def poses(street, cam):
        out = []
        for p in json.loads((street / "camera" / cam / "poses.json").read_text()):
            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat([p["heading"][k] for k in "xyzw"]).as_matrix()
            T[:3, 3] = [p["position"][k] for k in "xyz"]
            out.append(T)
        return out

    moved = []
    for cam in ("front_camera", "front_left_camera"):
        for exact, written in zip(poses(tiny_street, cam), poses(noisy, cam)):
            moved.append((np.degrees(Rotation.from_matrix(written[:3, :3] @ exact[:3, :3].T).magnitude()),
                          np.linalg.norm(written[:3, 3] - exact[:3, 3])))
    moved = np.array(moved)
    assert 0.05 < moved[:, 0].max() <= 0.5 * np.sqrt(3) + 1e-6 and 0.01 < moved[:, 1].max() < 1.0
    # One ego error per frame: the front-left camera's pose relative to the front one is the exact
    # rig's, up to the error's change over the 7 ms between the two cameras' time offsets (each
    # component changes at most 2 pi 2.9 / duration times its amplitude a second).
    rate = 2 * np.pi * 2.9 / (config.num_frames / config.frame_rate) * np.sqrt(3) * 0.007 * 1.2
    assert config.cameras.time_offsets[:2] == (0.004, 0.011)

    def relative(a, b):
        return a[:3, :3].T @ b[:3, :3], a[:3, :3].T @ (b[:3, 3] - a[:3, 3])

    for a, b, c, d in zip(poses(tiny_street, "front_camera"), poses(tiny_street, "front_left_camera"),
                          poses(noisy, "front_camera"), poses(noisy, "front_left_camera")):
        (r0, t0), (r1, t1) = relative(a, b), relative(c, d)
        assert np.degrees(Rotation.from_matrix(r0 @ r1.T).magnitude()) < 0.5 * rate
        assert np.linalg.norm(t0 - t1) < 0.1 * rate + 0.002
    assert (tiny_street / "lidar/poses.json").read_text() == (noisy / "lidar/poses.json").read_text()
    assert filecmp.cmp(tiny_street / "camera/front_camera/03.jpg", noisy / "camera/front_camera/03.jpg", shallow=False)


def test_pose_smoothness_counts_rotation_and_translation_in_their_units() -> None:
    """A middle image turned by one expected rotation and moved by one expected translation off its
    neighbours' line pays 2 (both in units), the same as the identity prior pays for it alone."""
    poses = ImagePoseCorrection([np.array([0.0, 0.1, 0.3])])
    with torch.no_grad():
        poses.rotation[1, 2] = math.radians(0.5)
        poses.translation[1, 0] = 0.1
    assert float(poses.smoothness(0.5, 0.1)) == pytest.approx(2.0, rel=1e-5)
    with torch.no_grad():  # a wander linear in time: nothing to pay
        poses.rotation.copy_(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.01], [0.0, 0.0, 0.03]]))
        poses.translation.zero_()
    assert float(poses.smoothness(0.5, 0.1)) == pytest.approx(0.0, abs=1e-9)
