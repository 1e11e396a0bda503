"""Camera calibration refinement (issue 45): the correction is an exact rigid motion in the
camera frame (against scipy), identity at the start, and a camera turned by a degree is found
again from its images alone through the differentiable rasterizer."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from idsplat_ns.model.camera_refinement import RigCorrection
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


def test_a_turned_camera_is_found_again_from_its_images() -> None:
    """A scene of Gaussians seen by a camera whose calibration says it looks 1 degree to the left
    of where it does: fitting only the correction to the true images recovers the turn."""
    torch.manual_seed(0)
    n = 400
    means = torch.stack([torch.rand(n) * 16 - 8, torch.rand(n) * 8 - 4, torch.rand(n) * 20 + 10], -1)  # in front
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1)
    scales = torch.full((n, 3), 0.25)
    opacities = torch.full((n,), 0.9)
    colours = torch.rand(n, 3)
    K = torch.tensor([[80.0, 0, 48], [0, 80.0, 32], [0, 0, 1]])
    true_view = torch.eye(4)
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("y", 1.0, degrees=True).as_matrix()
    told_view = torch.as_tensor(turn, dtype=torch.float32) @ true_view  # the calibration's (wrong) view

    def render(view):
        return rasterize_camera(means, quats, scales, opacities, colours, view[None], K[None], 96, 64,
                                backend="torch").features[0]

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
    corrected = (rig(told_view, 0) @ torch.linalg.inv(true_view)).detach().numpy()
    residual = np.degrees(np.linalg.norm(Rotation.from_matrix(corrected[:3, :3].astype(np.float64)).as_rotvec()))
    print(f"L1 {before:.4f} -> {after:.4f}; turn left after fitting {residual:.3f} deg (was 1 deg)")
    assert after < 0.5 * before
    assert residual < 0.2


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
