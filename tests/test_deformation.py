"""Non-rigid instances (model/deformation.py): the encoding and code interpolation against closed
forms, no offset at the start and none outside the deformable instances, the offset applied in
the canonical frame before the rigid pose, gradients against finite differences, and a fit of a
walking motion that the rigid model cannot follow, checked at held-out times."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from idsplat_ns.model.deformation import InstanceDeformation, interpolate_codes, position_encoding
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.scene_model import DecoderConfig, SceneModel
from idsplat_ns.model.trajectories import InstanceTrajectories


def test_position_encoding_is_the_sine_cosine_series():
    x = torch.tensor([[0.3, -1.2, 2.0]])
    enc = position_encoding(x, 2)
    expected = [0.3, -1.2, 2.0] + [math.sin(v * f) for f in (1, 2) for v in (0.3, -1.2, 2.0)] \
        + [math.cos(v * f) for f in (1, 2) for v in (0.3, -1.2, 2.0)]
    assert enc.shape == (1, 15)
    assert torch.allclose(enc[0], torch.tensor(expected), atol=1e-6)
    assert torch.equal(position_encoding(x, 0), x)


def test_codes_interpolate_linearly_between_steps_and_hold_at_the_ends():
    times = torch.tensor([0.0, 1.0, 3.0], dtype=torch.float64)
    codes = torch.tensor([[[0.0], [2.0], [6.0]]])  # [D=1, F=3, C=1]
    at = lambda t: float(interpolate_codes(codes, times, t)[0, 0])  # noqa: E731
    assert at(0.0) == 0.0 and at(1.0) == 2.0 and at(3.0) == 6.0
    assert at(0.25) == pytest.approx(0.5) and at(2.0) == pytest.approx(4.0)
    assert at(-5.0) == 0.0 and at(9.0) == 6.0


def _deformation(ids=(2,), steps=4, seed=0) -> InstanceDeformation:
    return InstanceDeformation(np.arange(steps, dtype=np.float64) * 0.1, np.array(ids), latent_dim=4, hidden=16,
                               position_freqs=2, seed=seed)


def test_no_offset_at_the_start_and_never_outside_the_deformable_instances():
    d = _deformation(ids=(2,))
    means = torch.randn(30, 3)
    ids = torch.tensor([0] * 10 + [1] * 10 + [2] * 10)
    assert torch.equal(d.offsets(means, ids, 0.15), torch.zeros(30, 3))
    with torch.no_grad():
        d.mlp[-1].weight.normal_()
    off = d.offsets(means, ids, 0.15)
    assert torch.equal(off[:20], torch.zeros(20, 3)) and (off[20:].norm(dim=1) > 0).all()
    # Different times give different codes, so different offsets.
    assert not torch.allclose(off[20:], d.offsets(means, ids, 0.25)[20:])


def test_gradients_match_finite_differences():
    d = _deformation().double()
    with torch.no_grad():
        d.mlp[-1].weight.normal_(0.0, 0.5)
    means = torch.randn(6, 3, dtype=torch.float64)
    ids = torch.full((6,), 2)
    target = torch.randn(6, 3, dtype=torch.float64)

    def loss():
        return ((d.offsets(means, ids, 0.13) - target) ** 2).sum()

    loss().backward()
    for param, index in ((d.codes, (0, 1, 2)), (d.mlp[0].weight, (3, 5))):
        eps = 1e-6
        with torch.no_grad():
            param[index] += eps
            up = float(loss())
            param[index] -= 2 * eps
            down = float(loss())
            param[index] += eps
        assert float(param.grad[index]) == pytest.approx((up - down) / (2 * eps), rel=1e-5, abs=1e-8)


def _walker(times: np.ndarray):
    """A walker's canonical points (legs below 0.9 m swing in x, opposite for left and right),
    its rigid pose (walking along x at 1.4 m/s, turned 90 degrees) and its points in the world at t."""
    rng = np.random.default_rng(0)
    canon = np.concatenate([rng.uniform([-0.2, -0.2, 0.0], [0.2, 0.2, 1.7], (200, 3))])
    left = canon[:, 1] > 0

    def swing(t):  # legs: 0.25 m at 1 Hz, left and right in opposite phase; torso rigid
        s = 0.25 * math.sin(2 * math.pi * 1.0 * t) * (0.9 - canon[:, 2]).clip(0) / 0.9
        return np.where(left, s, -s)

    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    poses[:, :3, :3] = R
    poses[:, 0, 3] = 1.4 * times

    def world(t):
        local = canon.copy()
        local[:, 0] += swing(t)
        return local @ R.T + np.array([1.4 * t, 0.0, 0.0])

    return canon, poses, world


def test_a_walking_motion_is_fitted_and_held_out_times_follow_it():
    train_t = np.arange(0.0, 2.0, 0.1)  # 10 Hz, as the data
    held_t = train_t[:-1] + 0.05  # between two training frames, as the interleaved eval frames
    canon, poses, world = _walker(train_t)
    traj = InstanceTrajectories(train_t, np.array([1]), poses[None], np.ones((1, len(train_t)), bool), refine=False)
    g = GaussianSet(len(canon))
    with torch.no_grad():
        g.means.copy_(torch.from_numpy(canon).float())
        g.instance_ids.fill_(1)
    deform = InstanceDeformation(train_t, np.array([1]), latent_dim=8, hidden=64, position_freqs=4, seed=0)
    sm = SceneModel(g, 1, DecoderConfig(), traj, deformation=deform)
    g.means.requires_grad_(False)  # the shape is fixed: only the deformation learns

    def err(times):
        with torch.no_grad():
            return float(np.mean([np.linalg.norm(sm.posed_gaussians(float(t))["means"].double().numpy() - world(t), axis=1).mean()
                                  for t in times]))

    rigid = err(held_t)
    opt = torch.optim.Adam(deform.parameters(), lr=3e-3)
    targets = [torch.from_numpy(world(t)).float() for t in train_t]
    for it in range(400):
        k = it % len(train_t)
        loss = ((sm.posed_gaussians(float(train_t[k]))["means"] - targets[k]) ** 2).sum(dim=1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    fitted_train, fitted_held = err(train_t), err(held_t)
    assert rigid > 0.03  # the rigid model misses the legs by centimetres
    assert fitted_train < 0.4 * rigid
    # Held-out times interpolate the codes of their two training neighbours; the motion between
    # two frames 0.1 s apart is close to linear, so they follow it nearly as well.
    assert fitted_held < 0.45 * rigid


def test_the_offset_is_applied_in_the_canonical_frame_before_the_pose():
    times = np.array([0.0, 1.0])
    poses = np.tile(np.eye(4), (2, 2, 1, 1))
    poses[:, :, :3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    poses[:, :, :3, 3] = [5.0, 0.0, 0.0]
    traj = InstanceTrajectories(times, np.array([1, 2]), poses, np.ones((2, 2), bool), refine=False)
    g = GaussianSet(3)
    with torch.no_grad():
        g.means.copy_(torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        g.instance_ids.copy_(torch.tensor([0, 1, 2]))
    deform = InstanceDeformation(times, np.array([2]), latent_dim=2, hidden=8, position_freqs=0)
    with torch.no_grad():
        deform.mlp[-1].bias.copy_(torch.tensor([0.5, 0.0, 0.0]))  # +0.5 m along canonical x
    sm = SceneModel(g, 1, DecoderConfig(), traj, deformation=deform)
    means = sm.posed_gaussians(0.5)["means"]
    assert torch.allclose(means[0], torch.tensor([1.0, 0.0, 0.0]))  # background: as it is
    assert torch.allclose(means[1], torch.tensor([5.0, 1.0, 0.0]))  # rigid instance: R p + t
    assert torch.allclose(means[2], torch.tensor([5.0, 1.5, 0.0]))  # canonical x becomes world y


def test_the_initial_field_depends_on_the_seed_only():
    times = np.array([0.0, 1.0])
    a = InstanceDeformation(times, np.array([1]), seed=3)
    torch.rand(1000)  # the global generator moves on
    b = InstanceDeformation(times, np.array([1]), seed=3)
    c = InstanceDeformation(times, np.array([1]), seed=4)
    for pa, pb in zip(a.parameters(), b.parameters()):
        assert torch.equal(pa, pb)
    assert not torch.equal(a.mlp[0].weight, c.mlp[0].weight)
