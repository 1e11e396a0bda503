"""Sensor fidelity in the scene model: instance velocities (against finite differences), a moving
instance seen through a rolling shutter (closed form), world-frame view directions for the RGB
decoder, and checkpoints with or without them."""

from __future__ import annotations

import math

import numpy as np
import torch

from idsplat_ns.data.camera import Intrinsics, RollingShutter, pixel_rays
from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.model.camera_shutter import ImageShutter
from idsplat_ns.model.composition import compose_gaussians, gaussian_velocities
from idsplat_ns.model.decoders import RGBDecoderCNN
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.scene_model import DecoderConfig, SceneModel, ray_directions
from idsplat_ns.model.trajectories import InstanceTrajectories


def _turning_trajectories() -> InstanceTrajectories:
    times = np.array([0.0, 0.4, 0.9, 1.3])
    poses = np.stack([
        np.stack([make_pose(rot_z(0.7 * t + 0.3 * t * t), [5 * t, 2 * t * t, 0.1 * t]) for t in times]),
        np.stack([make_pose(rot_z(-0.2 * t), [1 - 3 * t, 4.0, 0.0]) for t in times]),
    ])
    valid = np.ones((2, 4), bool)
    valid[1, 2:] = False  # instance 7: its first two steps only (present to 0.6 s with the margin)
    return InstanceTrajectories(times, np.array([3, 7]), poses, valid, dtype=torch.float64)


def test_instance_velocities_are_the_time_derivative_of_the_poses():
    traj = _turning_trajectories()
    gen = torch.Generator().manual_seed(0)
    means = torch.randn(20, 3, generator=gen, dtype=torch.float64)
    quats = torch.randn(20, 4, generator=gen, dtype=torch.float64)
    ids = torch.tensor([0] * 6 + [3] * 8 + [7] * 6)
    for t in (0.2, 0.61, 0.45):
        R, trans, present, lin, ang = traj.motion_at(t)
        world, _, keep = compose_gaussians(means, quats, ids, R, trans, present, traj.instance_ids)
        vel = gaussian_velocities(world, ids[keep], trans, lin, ang, traj.instance_ids)
        h = 1e-6  # inside one segment: the motion is smooth there
        ahead = compose_gaussians(means, quats, ids, *traj.poses_at(t + h), traj.instance_ids)[0]
        behind = compose_gaussians(means, quats, ids, *traj.poses_at(t - h), traj.instance_ids)[0]
        torch.testing.assert_close(vel, (ahead - behind) / (2 * h), atol=1e-6, rtol=1e-6)
        assert not vel[ids[keep] == 0].any() and vel[ids[keep] == 3].abs().max() > 1
    # The same poses as poses_at.
    for a, b in zip(traj.motion_at(0.7)[:3], traj.poses_at(0.7)):
        assert torch.equal(a, b)


W, H, F = 64, 48, 50.0
K = torch.tensor([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])


def _centroid(alpha: torch.Tensor) -> torch.Tensor:
    a = alpha[..., 0].double()
    ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    return torch.stack([(a * xs).sum() / a.sum(), (a * ys).sum() / a.sum()])


def test_moving_instance_through_a_rolling_shutter_lands_at_its_row_time():
    # One instance Gaussian moving along x at 15 m/s, 6 m ahead of a static camera (world = camera
    # frame); a top-to-bottom readout of 50 ms. It is seen where it was when its row was exposed.
    vx, y, z, x0, R, t = 15.0, 1.5, 6.0, -4.0, 0.05, 0.25
    times = np.array([0.0, 1.0])
    poses = np.stack([[make_pose(np.eye(3), [x0 + vx * s, y, z]) for s in times]])
    traj = InstanceTrajectories(times, np.array([1]), poses, np.ones((1, 2), bool))
    g = GaussianSet(1)
    with torch.no_grad():
        g.scales.fill_(math.log(0.1))
        g.opacities.fill_(2.0)
    g.instance_ids.fill_(1)
    sm = SceneModel(g, 1, DecoderConfig(), traj)
    shutter = ImageShutter(RollingShutter(R, "top_to_bottom"), W, H, np.zeros(3), np.zeros(3))
    with torch.no_grad():
        rolling = sm.render_camera(torch.eye(4), K, W, H, t, shutter=shutter)["accumulation"]
        plain = sm.render_camera(torch.eye(4), K, W, H, t)["accumulation"]
    row = F * y / z + H / 2
    tau = (row - H / 2) / (H - 1) * R
    expect = torch.tensor([F * (x0 + vx * (t + tau)) / z + W / 2, row], dtype=torch.float64)
    torch.testing.assert_close(_centroid(rolling), expect, atol=5e-3, rtol=0)
    assert abs(float(_centroid(plain)[0] - expect[0])) > 1.0  # without the shutter it is elsewhere
    # At half resolution the same physical row keeps its time: the point moves with the image.
    with torch.no_grad():
        half = sm.render_camera(torch.eye(4), K * torch.tensor([[0.5], [0.5], [1.0]]), W // 2, H // 2, t,
                                shutter=shutter)["accumulation"]
    a = half[..., 0].double()
    ys, xs = torch.meshgrid(torch.arange(H // 2) + 0.5, torch.arange(W // 2) + 0.5, indexing="ij")
    torch.testing.assert_close(torch.stack([(a * xs).sum() / a.sum(), (a * ys).sum() / a.sum()]) * 2, expect,
                               atol=0.03, rtol=0)


def test_ray_directions_match_the_camera_model():
    pose = make_pose(rot_z(0.6) @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), [3.0, -2.0, 1.5])
    intr = Intrinsics(fx=40.0, fy=42.0, cx=15.5, cy=11.0, width=30, height=20)
    viewmat = torch.from_numpy(np.linalg.inv(pose))
    d = ray_directions(viewmat, torch.from_numpy(intr.K), 30, 20)
    v, u = np.meshgrid(np.arange(20) + 0.5, np.arange(30) + 0.5, indexing="ij")
    _, ref = pixel_rays(np.c_[u.ravel(), v.ravel()], pose, intr)
    np.testing.assert_allclose(d.reshape(-1, 3).numpy(), ref, atol=1e-12)


def test_decoder_uses_view_directions_and_checkpoints_keep_their_choice():
    dec = RGBDecoderCNN(4, 2, 8, 3, 1, view_dim=3)
    torch.nn.init.normal_(dec.out.weight, std=0.5)
    base, feats, emb = torch.full((1, 5, 6, 3), 0.4), torch.zeros(1, 5, 6, 4), torch.zeros(1, 2)
    up = torch.zeros(1, 5, 6, 3)
    up[..., 2] = 1.0
    side = torch.zeros(1, 5, 6, 3)
    side[..., 0] = 1.0
    assert (dec(base, feats, emb, up) - dec(base, feats, emb, side)).abs().max() > 1e-3

    g = GaussianSet(40)
    with torch.no_grad():
        g.means.copy_(torch.randn(40, 3, generator=torch.Generator().manual_seed(1)) + torch.tensor([0.0, 0.0, 4.0]))
        g.scales.fill_(math.log(0.3))
    old = SceneModel(g, 1, DecoderConfig())  # a run without view directions
    torch.nn.init.normal_(old.rgb_decoder.out.weight, std=0.3)
    state = old.state_dict()
    new = SceneModel(GaussianSet(40), 1, DecoderConfig(), view_directions=True)
    assert new.rgb_decoder.inp.weight.shape[1] == 13 + 8 + 3
    new.decoder_like(state)
    new.load_state_dict(state)
    assert not new.view_directions
    with torch.no_grad():
        torch.testing.assert_close(new.render_camera(torch.eye(4), K, W, H, None)["rgb"],
                                   old.render_camera(torch.eye(4), K, W, H, None)["rgb"])
    # And back: a run with view directions into a model configured without.
    new.set_view_directions(True)
    plain = SceneModel(GaussianSet(40), 1, DecoderConfig())
    plain.decoder_like(new.state_dict())
    plain.load_state_dict(new.state_dict())
    assert plain.view_directions
