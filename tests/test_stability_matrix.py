"""Stability matrix: one case per numerical extreme of issue 22, table-driven.

Every case returns its outputs and the leaves it differentiates. The harness asserts every output
finite, every torch output float32 (host-side maths, the CT model and the time/recentring code,
is float64 by design and returns numpy), and every gradient of a weighted sum of the outputs
finite; each case asserts its own "sensible" result. docs/stability.md lists the cases with the
code that guards each. The camera extremes already in tests/test_render_stability.py (scales,
opacities, near plane, degenerate quaternions, a 1e4 m offset) are not repeated here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pytest
import torch

from idsplat_ns.data.geometry import rot_z
from idsplat_ns.data.scene import Scene, recentring_transform
from idsplat_ns.instances.smoothing import smooth_trajectory
from idsplat_ns.instances.smoothing.ct_model import (
    ct_increment, ct_increment_jacobian, ct_propagate, motion_residual,
)  # fmt: skip
from idsplat_ns.instances.static_conversion import convert_static_instances
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks
from idsplat_ns.model.gaussians import GaussianSet
from idsplat_ns.model.lidar_head import LidarHead
from idsplat_ns.model.lidar_losses import lidar_losses
from idsplat_ns.model.lidar_render import LidarRayBatch, render_lidar_rays, time_bins
from idsplat_ns.model.scene_model import DecoderConfig, SceneModel
from idsplat_ns.model.trajectories import InstanceTrajectories
from idsplat_ns.render import rasterize_camera, rasterize_lidar
from idsplat_ns.render.projection import project_gaussians
from idsplat_ns.render.reference import rasterize_dense
from test_render_lidar import _dense_lidar

K = torch.tensor([[30.0, 0, 16], [0, 30, 12], [0, 0, 1]])  # 32 x 24 pinhole
W, H = 32, 24
IDENTITY_Q = torch.tensor([1.0, 0.0, 0.0, 0.0])

Outputs = dict  # name -> Tensor (float32, checked) or np.ndarray (host float64)


@dataclass(frozen=True)
class Case:
    name: str
    run: Callable[[], tuple[Outputs, list[torch.Tensor]]]


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------


def _leaf(x, dtype=torch.float32) -> torch.Tensor:
    return torch.as_tensor(x, dtype=dtype).clone().requires_grad_()


def _camera(means, scales, opacity=0.8, viewmat=None, quats=None) -> tuple[Outputs, list[torch.Tensor]]:
    """Render one camera with the tile rasterizer; all inputs become leaves."""
    n = means.shape[0]
    leaves = [_leaf(means), _leaf(IDENTITY_Q.repeat(n, 1) if quats is None else quats), _leaf(scales),
              _leaf(torch.full((n,), opacity)), _leaf(torch.linspace(0, 1, 3 * n).reshape(n, 3)),
              _leaf(torch.eye(4) if viewmat is None else viewmat)]  # fmt: skip
    m, q, s, o, f, vm = leaves
    out = rasterize_camera(m, q, s, o, f, vm[None], K[None], W, H, backend="torch")
    return {"features": out.features, "alpha": out.alpha, "depth": out.depth, "median_depth": out.median_depth,
            "radii": out.radii, "instance_id": out.instance_id}, leaves  # fmt: skip


def _lidar(means, scales, az, el, opacity=0.8, **kw) -> tuple[Outputs, list[torch.Tensor]]:
    n = means.shape[0]
    leaves = [_leaf(means), _leaf(scales), _leaf(torch.full((n,), opacity)), _leaf(torch.linspace(0, 1, 2 * n).reshape(n, 2))]
    m, s, o, f = leaves
    out = rasterize_lidar(m, IDENTITY_Q.repeat(n, 1), s, o, f, torch.eye(4), torch.as_tensor(az, dtype=torch.float32),
                          torch.as_tensor(el, dtype=torch.float32), **kw)  # fmt: skip
    return {"features": out.features, "alpha": out.alpha, "range": out.range, "median_range": out.median_range}, leaves


def _fd_jacobian(fn: Callable[[np.ndarray], np.ndarray], x: np.ndarray, rel: float = 1e-7) -> np.ndarray:
    """Central differences of ``fn`` [M] at ``x`` [P]: [M, P]."""
    cols = []
    for i in range(len(x)):
        h = rel * max(1.0, abs(x[i]))
        e = np.zeros_like(x)
        e[i] = h
        cols.append((fn(x + e) - fn(x - e)) / (2 * h))
    return np.stack(cols, axis=1)


def _trajectories(times, positions, yaws, valid=None) -> InstanceTrajectories:
    """One instance with the given step positions [F, 3] and yaws [F] (radians)."""
    F = len(times)
    poses = np.tile(np.eye(4), (1, F, 1, 1))
    for k in range(F):
        poses[0, k, :3, :3] = rot_z(yaws[k])
        poses[0, k, :3, 3] = positions[k]
    valid = np.ones((1, F), bool) if valid is None else np.asarray(valid)[None]
    return InstanceTrajectories(np.asarray(times, np.float64), np.array([1]), poses, valid)


def _poses_case(traj: InstanceTrajectories, times) -> tuple[Outputs, list[torch.Tensor]]:
    Rs, ts, present = zip(*(traj.poses_at(t) for t in times))
    return {"R": torch.stack(Rs), "t": torch.stack(ts), "present": torch.stack(present)}, [traj.positions, traj.rotation_deltas]


# ---------------------------------------------------------------------------------------------
# the cases
# ---------------------------------------------------------------------------------------------


def ct_curvature_zero():
    """kappa = 1e-9: the CT step is the straight line [v dt, 0], its Jacobian the straight line's."""
    v, kappa, dt = 12.0, 1e-9, 0.1
    theta, dx, dy = ct_increment(v, kappa, dt)
    assert theta == pytest.approx(1.2e-9, rel=1e-12)
    assert dx == pytest.approx(v * dt, rel=1e-15) and abs(dy - 0.5 * kappa * (v * dt) ** 2) < 1e-18
    jac = ct_increment_jacobian(v, kappa, dt)
    # The straight line's Jacobian; the entries it leaves at 0 are O(kappa) = 1e-9 here.
    np.testing.assert_allclose(jac, [[kappa * dt, v * dt], [dt, 0.0], [0.0, 0.5 * (v * dt) ** 2]], atol=1e-9)
    fd = _fd_jacobian(lambda p: np.array(ct_increment(p[0], p[1], dt)), np.array([v, kappa]), rel=1e-6)
    np.testing.assert_allclose(jac, fd, atol=1e-8)
    pose = np.eye(4)
    pose[:3, 3] = (5.0, -2.0, 0.3)
    shared = rot_z(0.4)
    moved = ct_propagate(pose, shared, v, kappa, dt)
    np.testing.assert_allclose(moved[:3, 3], pose[:3, 3] + shared[:, 0] * v * dt, atol=1e-9)  # along motion x
    err, jacs = motion_residual(pose, moved, v, kappa, shared, dt)
    assert np.abs(err).max() < 1e-12
    return {"increment": np.array([theta, dx, dy]), "jac": jac, **{f"H{i}": h for i, h in enumerate(jacs)}}, []


def ct_curvature_large():
    """kappa = 1e3 1/m (a 1 mm radius), theta = 1200 rad: the step stays on its circle."""
    v, kappa, dt = 12.0, 1e3, 0.1
    theta, dx, dy = ct_increment(v, kappa, dt)
    # On the circle of radius 1/kappa through the origin, centred at (0, 1/kappa).
    assert math.hypot(dx, dy - 1 / kappa) == pytest.approx(1 / kappa, rel=1e-9)
    assert math.hypot(dx, dy) <= 2 / kappa + 1e-12
    jac = ct_increment_jacobian(v, kappa, dt)
    fd = _fd_jacobian(lambda p: np.array(ct_increment(p[0], p[1], dt)), np.array([v, kappa]), rel=1e-9)
    np.testing.assert_allclose(jac, fd, rtol=1e-4, atol=1e-8)
    pose = np.eye(4)
    moved = ct_propagate(pose, rot_z(0.2), v, kappa, dt)
    err, jacs = motion_residual(pose, moved, v, kappa, rot_z(0.2), dt)
    assert np.abs(err).max() < 1e-9
    return {"increment": np.array([theta, dx, dy]), "jac": jac, "moved": moved, **{f"H{i}": h for i, h in enumerate(jacs)}}, []


def ct_speed_zero():
    """v = 0 at any curvature: no turn, no displacement, finite Jacobian (d/dv exists)."""
    kappa, dt = 0.3, 0.1
    theta, dx, dy = ct_increment(0.0, kappa, dt)
    assert (theta, dx, dy) == (0.0, 0.0, 0.0)
    jac = ct_increment_jacobian(0.0, kappa, dt)
    np.testing.assert_allclose(jac, [[kappa * dt, 0.0], [dt, 0.0], [0.0, 0.0]], atol=1e-15)
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 2.0, 3.0)
    np.testing.assert_array_equal(ct_propagate(pose, rot_z(1.0), 0.0, kappa, dt)[:3, 3], pose[:3, 3])
    return {"increment": np.array([theta, dx, dy]), "jac": jac}, []


def smoother_waits_at_a_light():
    """Drive, wait 2 s at a light, drive on: the smoothed car stays put while it waits."""
    dt, v = 0.1, 8.0
    x = np.concatenate([v * dt * np.arange(20), np.full(20, v * dt * 20), v * dt * (20 + np.arange(20))])
    times = np.arange(len(x)) * dt
    poses = np.tile(np.eye(4), (len(x), 1, 1))
    poses[:, 0, 3] = x
    poses[:, :3, 3] += np.random.default_rng(0).normal(0, 0.03, (len(x), 3))
    result = smooth_trajectory(times, poses, np.ones(len(x), bool))
    waiting = result.poses[24:36, :3, 3]  # away from the stop's ends, where the smoother lags
    assert np.ptp(waiting, axis=0).max() < 0.1
    # The step poses stay put; the CT states' speeds do not fall to 0 there (2.6-3.1 m/s measured):
    # docs/stability.md.
    return {"poses": result.poses, "speeds": result.speeds, "curvatures": result.curvatures}, []


def trajectory_curvature_zero():
    """Steps 1e-9 rad apart (a straight road): the slerp's small-angle branch, exact midpoint."""
    traj = _trajectories([0.0, 0.1, 0.2], [(0, 0, 0), (1, 0, 0), (2, 0, 0)], [0.0, 1e-9, 2e-9])
    out, leaves = _poses_case(traj, [0.05, 0.15])
    torch.testing.assert_close(out["t"][:, 0], torch.tensor([[0.5, 0.0, 0.0], [1.5, 0.0, 0.0]]))
    torch.testing.assert_close(out["R"][:, 0], torch.eye(3).expand(2, 3, 3))
    return out, leaves


def trajectory_curvature_large():
    """Consecutive steps turned by 3 rad and by exactly pi: slerp near and at the antipode."""
    traj = _trajectories([0.0, 0.1, 0.2], [(0, 0, 0), (0.1, 0, 0), (0.1, 0.1, 0)], [0.0, 3.0, 3.0 + math.pi])
    out, leaves = _poses_case(traj, [0.05, 0.1, 0.15])
    R = out["R"]
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3).expand_as(R), atol=1e-5, rtol=0)
    yaw_mid = math.atan2(float(R[0, 0, 1, 0]), float(R[0, 0, 0, 0]))
    assert yaw_mid == pytest.approx(1.5, abs=1e-5)  # half of the 3 rad turn
    return out, leaves


def trajectory_speed_zero():
    """A vehicle waiting at a light: identical steps, the pose stays exactly put in between."""
    F = 6
    traj = _trajectories(np.arange(F) * 0.1, [(4.0, -2.0, 0.5)] * F, [0.7] * F)
    out, leaves = _poses_case(traj, [0.0, 0.05, 0.23, 0.5])
    torch.testing.assert_close(out["t"], torch.tensor([[4.0, -2.0, 0.5]]).expand(4, 1, 3), rtol=0, atol=0)
    torch.testing.assert_close(out["R"], torch.from_numpy(rot_z(0.7)).float().expand(4, 1, 3, 3), rtol=0, atol=1e-7)
    return out, leaves


def one_frame_instance():
    """One valid step: constant pose within the span margin, absent outside; static when converted."""
    valid = [False, False, True, False, False]
    traj = _trajectories(np.arange(5) * 0.1, [(3.0, 1.0, 0.0)] * 5, [0.2] * 5, valid=valid)
    out, leaves = _poses_case(traj, [0.2, 0.24, 0.26])
    assert out["present"][:, 0].tolist() == [True, True, False]
    torch.testing.assert_close(out["t"][1, 0], torch.tensor([3.0, 1.0, 0.0]))
    poses = np.tile(np.eye(4), (5, 1, 1))
    inst = InstanceTrack(instance_id=1, label="car", canonical_points=np.zeros((20, 3)), canonical_colors=None, poses=poses,
                         valid=np.array(valid), point_counts=np.full(5, 20), fitness=np.ones(5), canonical_frame=2)  # fmt: skip
    tracks = InstanceTracks(np.arange(5), np.arange(5) * 0.1, [inst], [], {})
    converted = convert_static_instances(tracks)
    assert converted.instances == [] and len(converted.static_instances) == 1  # one frame shows no motion
    return out, leaves


def gaussian_scale_tiny():
    """1e-4 m Gaussians through the model's log-scale parameters: still drawn (the eps2d low-pass
    gives them a pixel), in the camera and the lidar."""
    g = GaussianSet(2)
    with torch.no_grad():
        g.means.copy_(torch.tensor([[0.0, 0.0, 4.0], [0.3, 0.2, 6.0]]))
        g.scales.fill_(math.log(1e-4))
        g.opacities.fill_(2.0)
    a = g.activated()
    out = rasterize_camera(a["means"], a["quats"], a["scales"], a["opacities"], a["colors"], torch.eye(4)[None], K[None],
                           W, H, backend="torch")  # fmt: skip
    assert float(out.alpha.max()) > 0.3 and (out.radii > 0).all()
    in_lidar = a["means"][:, [2, 0, 1]]  # camera z forward -> lidar x forward
    d = in_lidar.detach()
    az, el = torch.atan2(d[:, 1], d[:, 0]), torch.atan2(d[:, 2], d[:, :2].norm(dim=1))  # one ray at each centre
    lid = rasterize_lidar(in_lidar, a["quats"], a["scales"], a["opacities"], a["colors"], torch.eye(4), az, el)
    assert (lid.alpha > 0.3).all()
    torch.testing.assert_close(lid.range[:, 0], d.norm(dim=1), rtol=1e-6, atol=0)
    return {"alpha": out.alpha, "depth": out.depth, "features": out.features, "lidar_alpha": lid.alpha,
            "lidar_range": lid.range}, [g.means, g.scales, g.opacities, g.features_rgb]  # fmt: skip


def gaussian_scale_huge():
    """1e3 m Gaussians: they cover every pixel and ray, alpha stays at the opacity (bounded)."""
    means = torch.tensor([[0.0, 0.0, 5.0], [0.5, 0.0, 8.0]])
    cam, leaves = _camera(means, torch.tensor([[1e3] * 3, [0.2] * 3]), opacity=0.6)
    assert (cam["alpha"] >= 0.59).all() and (cam["alpha"] <= 0.999).all()
    az = torch.linspace(-math.pi, math.pi, 9)
    lid, lid_leaves = _lidar(torch.tensor([[5.0, 0.0, 0.0]]), torch.tensor([[1e3] * 3]), az, torch.zeros(9), opacity=0.6)
    torch.testing.assert_close(lid["alpha"], torch.full((9, 1), 0.6), atol=1e-3, rtol=0)
    return cam | {f"lidar_{k}": v for k, v in lid.items()}, leaves + lid_leaves


def points_ten_kilometres_away():
    """A 10 m Gaussian 1e4 m away: depth and range come out as 1e4 m to float32 precision."""
    cam, leaves = _camera(torch.tensor([[0.0, 0.0, 1e4]]), torch.full((1, 3), 10.0))
    hit = cam["alpha"] > 0
    assert hit.any() and torch.allclose(cam["depth"][hit], torch.tensor(1e4), rtol=1e-6)
    lid, lid_leaves = _lidar(torch.tensor([[1e4, 0.0, 0.0]]), torch.full((1, 3), 10.0), torch.zeros(2), torch.tensor([0.0, 1e-4]))
    torch.testing.assert_close(lid["range"], torch.full((2, 1), 1e4), rtol=1e-6, atol=0)
    return cam | {f"lidar_{k}": v for k, v in lid.items()}, leaves + lid_leaves


UTM = np.array([452_311.37, 5_411_287.91, 34.2])  # metres: a UTM-like world offset (~5e6 m)


def world_offset_utm():
    """A scene 5e6 m from its world origin, through the data path's recentring (world_from_raw):
    float32 renders equal those of the same scene built at the origin."""
    local = np.array([[0.1, -0.2, 4.0], [0.6, 0.3, 6.0], [-0.7, 0.1, 5.0]])
    cam_local = np.eye(4)
    cam_local[:3, 3] = (0.03, -0.01, 0.0)
    first_ego_raw = np.eye(4)
    first_ego_raw[:3, 3] = UTM
    world_from_raw = recentring_transform(first_ego_raw)
    raw_points, raw_cam = local + UTM, cam_local.copy()
    raw_cam[:3, 3] += UTM
    # Without recentring, float32 keeps 0.5 m steps at 5e6 m: the guard is needed.
    assert np.abs(raw_points.astype(np.float32).astype(np.float64) - raw_points).max() > 0.01
    scene = Scene("utm", "synthetic", None, np.arange(1), np.zeros(1), first_ego_raw[None], [], [], world_from_raw=world_from_raw)
    means = scene.raw_points_to_world(raw_points)  # float64 on the host, then float32
    viewmat = np.linalg.inv(world_from_raw @ raw_cam)
    scales = torch.full((3, 3), 0.3)
    out, leaves = _camera(torch.from_numpy(means).float(), scales, viewmat=torch.from_numpy(viewmat).float())
    ref, _ = _camera(torch.from_numpy(local).float(), scales, viewmat=torch.from_numpy(np.linalg.inv(cam_local)).float())
    torch.testing.assert_close(out["alpha"], ref["alpha"], atol=1e-6, rtol=0)
    torch.testing.assert_close(out["depth"], ref["depth"], atol=1e-5, rtol=0)
    return out, leaves


def microsecond_timestamps():
    """Waymo-like microsecond stamps near 1.7e9 s: seconds from float64 host maths, and the
    trajectories and lidar time bins work even on absolute seconds."""
    raw_us = np.int64(1_700_000_000_123_456) + np.arange(5, dtype=np.int64) * 100_000  # 0.1 s apart
    scene = Scene("t", "synthetic", None, np.arange(5), np.zeros(5), np.tile(np.eye(4), (5, 1, 1)), [], [],
                  time_origin_raw=float(raw_us[0]), raw_time_unit_seconds=1e-6)  # fmt: skip
    seconds = scene.raw_time_to_seconds(raw_us)
    np.testing.assert_allclose(seconds, np.arange(5) * 0.1, atol=1e-7)
    absolute = raw_us * 1e-6  # seconds since 1970, float64
    positions = [(2.0 * k, 0.0, 0.0) for k in range(5)]
    rel = _trajectories(seconds, positions, [0.0] * 5)
    traj = _trajectories(absolute, positions, [0.0] * 5)
    t = torch.tensor(float(absolute[1]) + 0.025, dtype=torch.float64, requires_grad=True)  # a learnable time
    R, trans, present = traj.poses_at(t)
    torch.testing.assert_close(trans, rel.poses_at(float(seconds[1]) + 0.025)[1], atol=1e-4, rtol=0)
    assert float(trans[0, 0]) == pytest.approx(2.5, abs=1e-4)
    bins, centres = time_bins(torch.from_numpy(absolute[0] + np.linspace(0, 0.1, 8)), 4)
    assert bins.tolist() == [0, 0, 1, 1, 2, 2, 3, 3]
    return {"R": R, "t": trans, "seconds": seconds}, [traj.positions, t]


def camera_inside_gaussian():
    """The camera inside 5 m Gaussians: the one centred in front is bounded (alpha <= its opacity,
    tile = dense reference), the ones centred on and behind the camera are culled."""
    means = torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 0.0], [0.0, 0.0, -0.5]])
    out, leaves = _camera(means, torch.full((3, 3), 5.0), opacity=0.8)
    assert out["radii"][0].tolist()[1:] == [0, 0] and out["radii"][0, 0] > 0
    assert (out["alpha"] <= 0.8 + 1e-6).all() and (out["alpha"] > 0.79).all()
    proj = project_gaussians(leaves[0], leaves[1], leaves[2], leaves[5][None], K[None], W, H)
    _, alpha_ref, _, _, _ = rasterize_dense(proj.means2d, proj.conics, proj.depths, proj.radii, leaves[3], leaves[4], W, H)
    torch.testing.assert_close(out["alpha"], alpha_ref, atol=1e-6, rtol=1e-5)
    return out, leaves


def lidar_grazing_plane():
    """Rays at -10 to -1.3 degrees over a thin ground plane 1.8 m below the sensor, and rays at and
    above the horizon. Tile rasterizer = dense reference (values and gradients) at grazing
    incidence; hit ranges grow as the ray flattens and never pass the plane; horizon rays miss."""
    h = 1.8
    # y offset: no two Gaussians at exactly the same range (the order of exact ties is arbitrary,
    # and tile and reference break them differently)
    xs, ys = torch.arange(0.25, 90.0, 0.5), torch.arange(-6.0, 6.0, 0.5) + 0.13
    X, Y = torch.meshgrid(xs, ys, indexing="ij")
    n = X.numel()
    means = torch.stack([X.reshape(-1), Y.reshape(-1), torch.full((n,), -h)], 1)
    el_deg = torch.tensor([-10.0, -5.0, -3.0, -2.0, -1.5, -1.3, 0.0, 0.5])
    el = torch.deg2rad(el_deg)
    az = torch.zeros_like(el)
    res = math.radians(0.2)
    leaves = [_leaf(means, torch.float64), _leaf(IDENTITY_Q.repeat(n, 1), torch.float64),
              _leaf(torch.tensor([0.3, 0.3, 1e-3]).repeat(n, 1), torch.float64), _leaf(torch.full((n,), 0.9), torch.float64),
              _leaf(torch.rand(n, 2, generator=torch.Generator().manual_seed(0)), torch.float64)]  # fmt: skip
    out = rasterize_lidar(*leaves, torch.eye(4, dtype=torch.float64), az.double(), el.double(), azimuth_resolution=res,
                          elevation_resolution=res)  # fmt: skip
    f, a, dsum = _dense_lidar(*leaves, az.double(), el.double(), 2 * math.pi / (8 * round(2 * math.pi / res / 8)), res)
    torch.testing.assert_close(out.alpha, a, atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(out.range * out.alpha, dsum, atol=1e-4, rtol=1e-5)
    g1 = torch.autograd.grad((out.range * out.alpha).sum() + out.features.sum(), leaves)
    g2 = torch.autograd.grad(dsum.sum() + f.sum(), leaves)
    for x, y in zip(g1, g2):
        torch.testing.assert_close(x, y, atol=1e-4, rtol=1e-4)
    analytic = h / torch.sin(-el[:6]).double()
    hit = out.range[:6, 0]
    assert (out.alpha[:6] > 0.95).all() and (out.alpha[6:] == 0).all()
    assert (hit[1:] > hit[:-1]).all() and (hit <= analytic * 1.001).all()
    # Splats 0.3 m wide are met before the true hit; at grazing incidence that is metres short.
    assert ((analytic - hit) / analytic).max() < 0.2
    # The float32 path (as trained) on the same rays.
    out32, leaves32 = _lidar(means, torch.tensor([0.3, 0.3, 1e-3]).repeat(n, 1), az, el, opacity=0.9,
                             azimuth_resolution=res, elevation_resolution=res)  # fmt: skip
    torch.testing.assert_close(out32["range"].double(), out.range, atol=2e-3, rtol=1e-4)
    return out32, leaves32


def empty_frames():
    """Nothing to render: no Gaussians in a camera, none near any ray, a lidar batch with no
    return, and a scene whose only Gaussians belong to an instance absent at the render time."""
    cam, leaves = _camera(torch.zeros(0, 3), torch.zeros(0, 3))
    assert (cam["alpha"] == 0).all() and (cam["depth"] == 0).all() and (cam["instance_id"] == -1).all()
    lid, lid_leaves = _lidar(torch.zeros(0, 3), torch.zeros(0, 3), torch.zeros(4), torch.zeros(4))
    assert (lid["alpha"] == 0).all()
    culled, culled_leaves = _lidar(torch.tensor([[0.0, 0.0, 50.0]]), torch.full((1, 3), 0.1), torch.zeros(4), torch.zeros(4))
    assert (culled["alpha"] == 0).all()
    # A sweep with no return: the depth, intensity and line-of-sight means have nothing to average.
    r = 6
    rays = LidarRayBatch(origins=torch.zeros(r, 3), directions=torch.tensor([[1.0, 0, 0]]).repeat(r, 1),
                         ranges=torch.zeros(r), intensities=torch.zeros(r), times=torch.zeros(r, dtype=torch.float64),
                         returned=torch.zeros(r, dtype=torch.bool))  # fmt: skip
    head = LidarHead(2, 8)
    g = {"means": lid_leaves[0], "quats": IDENTITY_Q.repeat(0, 1), "scales": lid_leaves[1], "opacities": lid_leaves[2],
         "features": lid_leaves[3]}  # fmt: skip
    render = render_lidar_rays(lambda t: g, rays, torch.eye(4), cutoff_ranges=torch.zeros(r))
    losses = lidar_losses(render, head(render.features), rays)
    assert losses["lidar_depth"] == 0 and losses["lidar_intensity"] == 0 and losses["lidar_ray_drop"] > 0
    # A scene model at a time when its only instance is absent: the background alone.
    sm = _scene_model(static=0)
    rendered = sm.render_camera(torch.eye(4), K, W, H, time=5.0)
    assert (rendered["accumulation"] == 0).all()
    outs = {**cam, **{f"lidar_{k}": v for k, v in lid.items()}, "culled_alpha": culled["alpha"], "rgb": rendered["rgb"],
            **{k: v for k, v in losses.items()}}  # fmt: skip
    return outs, leaves + lid_leaves + culled_leaves + list(head.parameters()) + list(sm.parameters())


def _scene_model(static: int = 20, instance: int = 20) -> SceneModel:
    """A small float32 scene: static Gaussians in front of the camera, one instance moving along x
    over 0..0.4 s, a lidar head."""
    gen = torch.Generator().manual_seed(3)
    n = static + instance
    g = GaussianSet(n, 13)
    with torch.no_grad():
        g.means.copy_(torch.randn(n, 3, generator=gen) * 0.5 + torch.tensor([0.0, 0.0, 5.0]))
        g.means[static:] -= torch.tensor([0.0, 0.0, 5.0])  # instance points in the canonical frame
        g.scales.fill_(math.log(0.2))
        g.features_rgb.normal_(generator=gen)
        g.features.normal_(0, 0.1, generator=gen)
        g.instance_ids[static:] = 1
    F = 5
    poses = np.tile(np.eye(4), (1, F, 1, 1))
    poses[0, :, 0, 3] = np.linspace(-1.0, 1.0, F)
    poses[0, :, 2, 3] = 5.0
    traj = InstanceTrajectories(np.arange(F) * 0.1, np.array([1]), poses, np.ones((1, F), bool))
    return SceneModel(g, 2, DecoderConfig(), traj, lidar_head_hidden=32, camera_time_offsets=True)


def float32_throughout():
    """The whole model, camera and lidar, with instances and a learnt time offset: float32 in,
    float32 out (the harness checks every dtype), gradients reach every parameter group."""
    sm = _scene_model()
    torch.nn.init.normal_(sm.rgb_decoder.out.weight, std=0.1)  # zero at init: no gradient would reach the embedding
    with torch.no_grad():
        sm.sensor_embedding.weight.normal_(0.0, 0.1)
    cam = sm.render_camera(torch.eye(4), K, W, H, time=0.15, sensor=1)
    r = 32
    gen = torch.Generator().manual_seed(4)
    dirs = torch.nn.functional.normalize(torch.randn(r, 3, generator=gen) * 0.1 + torch.tensor([0.0, 0.0, 1.0]), dim=1)
    rays = LidarRayBatch(origins=torch.zeros(r, 3), directions=dirs, ranges=torch.full((r,), 5.0),
                         intensities=torch.full((r,), 0.3), times=torch.linspace(0.1, 0.2, r, dtype=torch.float64),
                         returned=torch.ones(r, dtype=torch.bool))  # fmt: skip
    lid, head = sm.render_lidar(rays, torch.eye(4))
    params = dict(sm.named_parameters())
    assert all(p.dtype == torch.float32 for p in params.values())
    loss = cam["rgb"].sum() + lid.range.sum() + head.intensity.sum()
    grads = dict(zip(params, torch.autograd.grad(loss, list(params.values()), allow_unused=True, retain_graph=True)))
    for name in ("gaussians.means", "trajectories.positions", "trajectories.rotation_deltas", "camera_time_offset",
                 "sensor_embedding.weight", "lidar_head.mlp.0.weight"):  # fmt: skip
        assert grads[name] is not None and grads[name].abs().sum() > 0, name
    return {"rgb": cam["rgb"], "depth": cam["depth"], "range": lid.range, "intensity": head.intensity,
            "drop": head.ray_drop_logit}, list(params.values())  # fmt: skip


CASES = [Case(fn.__name__, fn) for fn in (
    ct_curvature_zero, ct_curvature_large, ct_speed_zero, smoother_waits_at_a_light,
    trajectory_curvature_zero, trajectory_curvature_large, trajectory_speed_zero, one_frame_instance,
    gaussian_scale_tiny, gaussian_scale_huge, points_ten_kilometres_away, world_offset_utm,
    microsecond_timestamps, camera_inside_gaussian, lidar_grazing_plane, empty_frames, float32_throughout,
)]  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_stability_matrix(case: Case) -> None:
    outputs, leaves = case.run()
    loss = torch.zeros((), dtype=torch.float64)
    for name, value in outputs.items():
        if isinstance(value, np.ndarray):
            assert np.all(np.isfinite(value)), name
            continue
        assert torch.isfinite(value.double()).all(), name
        if value.is_floating_point():
            assert value.dtype == torch.float32, f"{name} is {value.dtype}"
            if value.requires_grad:
                weights = torch.linspace(0.5, 1.5, value.numel(), dtype=value.dtype).reshape(value.shape)
                loss = loss + (value * weights).sum().double()
    if not leaves:
        return
    assert loss.requires_grad, "the case's outputs do not depend on its leaves"
    grads = torch.autograd.grad(loss, leaves, allow_unused=True)
    for i, g in enumerate(grads):
        assert g is None or torch.isfinite(g).all(), f"gradient of leaf {i} ({tuple(leaves[i].shape)})"
