"""Seed points of the instance-decomposed model on a hand-built scene: a box moving over a ground plane."""

from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.spatial.distance import cdist

from idsplat_ns.data.camera import CameraImage, Intrinsics
from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.data.lidar import LidarSweep, rays_from_points
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks
from idsplat_ns.model.initialisation import InitConfig
from idsplat_ns.data.geometry import interpolate_poses
from idsplat_ns.model.instance_init import instance_exclusion, instance_initial_points

F = 5
TIMES = np.arange(F) * 0.1
BOX_HALF = np.array([2.0, 1.0, 0.75])
BOX_Z = 1.25  # box centre height: bottom at 0.5 m, so the 0.3 m margin stays above the ground
INTR = Intrinsics(fx=60.0, fy=60.0, cx=40.0, cy=30.0, width=80, height=60)
RED, BLUE = np.array([255, 0, 0], np.uint8), np.array([0, 0, 255], np.uint8)


def _box_pose(k: float) -> np.ndarray:
    """The box drives 1 m per step along x and turns slightly."""
    return make_pose(rot_z(0.05 * k), np.array([-2.0 + 1.0 * k, 0.0, BOX_Z]))


def _box_surface(rng: np.random.Generator, n: int) -> np.ndarray:  # canonical points on the box faces
    p = rng.uniform(-1, 1, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = np.sign(p[np.arange(n), axis])
    return p * BOX_HALF


def _camera_to_world() -> np.ndarray:
    # At (0, -15, 1.25) looking along +y (OpenCV: x right = +x, y down = -z, z forward = +y).
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    return make_pose(R, np.array([0.0, -15.0, BOX_Z]))


def _scene(seed: int = 0):
    """Ground grid + the moving box per sweep; one camera image per frame that is red exactly where
    the box is at that frame's time (blue elsewhere)."""
    rng = np.random.default_rng(seed)
    canonical = _box_surface(rng, 400)
    gx, gy = np.meshgrid(np.linspace(-20, 20, 41), np.linspace(-20, 20, 41))
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    origin = np.array([0.0, -15.0, 2.0])
    sweeps, images, pixels = [], [], {}
    for k in range(F):
        box_world = canonical @ _box_pose(k)[:3, :3].T + _box_pose(k)[:3, 3]
        ground_k = ground + rng.normal(0, 0.01, ground.shape) * [1, 1, 0]
        pts = np.concatenate([ground_k, box_world])
        d, r = rays_from_points(np.repeat(origin[None], len(pts), 0), pts)
        n = len(pts)
        sweeps.append(LidarSweep(frame_index=k, time=TIMES[k], raw_timestamp=TIMES[k],
                                 sensor_to_world=make_pose(np.eye(3), origin), origins=np.repeat(origin[None], n, 0),
                                 directions=d, ranges=r, intensities=np.zeros(n, np.float32),
                                 times=np.full(n, TIMES[k]), returned=np.ones(n, bool), sensor_ids=np.zeros(n, np.int16)))
        im = CameraImage(camera="front", frame_index=k, time=TIMES[k] - 0.01, raw_timestamp=0.0,
                         camera_to_world=_camera_to_world(), intrinsics=INTR)
        img = np.tile(BLUE, (INTR.height, INTR.width, 1))
        dense = _box_surface(rng, 20000) @ _box_pose(k)[:3, :3].T + _box_pose(k)[:3, 3]
        proj = im.project(dense)
        uv = proj.uv[proj.valid].astype(int)
        img[np.clip(uv[:, 1], 0, INTR.height - 1), np.clip(uv[:, 0], 0, INTR.width - 1)] = RED
        pixels[k] = img
        images.append(im)
    ego = np.repeat(make_pose(np.eye(3), origin)[None], F, 0)
    scene = Scene(name="box", source="test", root=None, frame_indices=np.arange(F), frame_times=TIMES,
                  ego_poses=ego, images=images, lidar=sweeps)
    poses = np.stack([_box_pose(k) for k in range(F)])
    inst = InstanceTrack(instance_id=3, label="car", canonical_points=canonical, canonical_colors=None, poses=poses,
                         valid=np.ones(F, bool), point_counts=np.full(F, 400), fitness=np.ones(F), canonical_frame=2)
    tracks = InstanceTracks(np.arange(F), TIMES, [inst])
    return scene, tracks, ground, lambda im: pixels[im.frame_index]


def test_interpolate_poses_interpolates_and_extrapolates():
    steps = np.stack([_box_pose(k) for k in range(F)])
    out = interpolate_poses(TIMES, steps, np.array([0.1, 0.25, -0.05, 0.45]), extrapolate=True)
    assert np.allclose(out[0], _box_pose(1), atol=1e-12)
    assert np.allclose(out[1], _box_pose(2.5), atol=1e-12)  # the motion is linear in k
    assert np.allclose(out[2], _box_pose(-0.5), atol=1e-12)  # constant-velocity extrapolation
    assert np.allclose(out[3], _box_pose(4.5), atol=1e-12)


def test_exclusion_follows_the_box_in_time():
    _, tracks, _, _ = _scene()
    exclude = instance_exclusion(tracks, box_margin=0.3)
    centre_at_0 = _box_pose(0)[:3, 3]
    pts = np.stack([centre_at_0, centre_at_0, centre_at_0, _box_pose(3)[:3, 3] + [2.2, 0, 0], [0.0, 0.0, 0.0]])
    times = np.array([0.0, 0.3, 1.0, 0.3, 0.2])
    # Inside at t=0; the box has left by t=0.3; t=1.0 is past the span (+ half-step margin);
    # 0.2 m beyond the front face is within the 0.3 m margin; the ground below is not excluded.
    assert exclude(pts, times).tolist() == [True, False, False, True, False]


def test_instance_points_are_excluded_from_the_background():
    scene, tracks, ground, load = _scene()
    train = [im for im in scene.images if im.frame_index != 4]  # frame 4 held out
    cfg = InitConfig(points_per_lidar_point=0.5, seed=0)
    init = instance_initial_points(scene, tracks, cfg, load, images=train)
    ids = init.instance_ids
    assert set(np.unique(ids).tolist()) == {0, 3}
    # Instance 3: its canonical points, unchanged (canonical frame), coloured from its own images.
    assert np.allclose(init.means[ids == 3], tracks.instances[0].canonical_points)
    red = np.all(np.isclose(init.colors[ids == 3], [1.0, 0.0, 0.0]), axis=1)
    assert red.mean() > 0.95  # no occlusion test: back faces project onto the box too; a wrong pose/frame gives blue
    assert not np.any(np.all(np.isclose(init.colors[ids == 3], [0.0, 0.0, 1.0]), axis=1))
    # Background lidar: exactly the ground points of the 4 training frames, none of the box.
    static_lidar = init.means[(ids == 0) & init.is_lidar]
    assert len(static_lidar) == 4 * len(ground)
    assert np.all(np.abs(static_lidar[:, 2]) < 1e-9)
    # Random points scale with the background lidar points (0.5 per point).
    assert np.sum((ids == 0) & ~init.is_lidar) == 2 * len(ground)
    # Paper: half uniform in the lidar range's ball (radius: 95th percentile of the lidar distances
    # from the mean ego position), half beyond it with inverse distance uniform, up to 1 km.
    centre = np.array([0.0, -15.0, 2.0])
    lidar_range = np.percentile(np.linalg.norm(static_lidar - centre, axis=1), 95)
    rand = init.means[(ids == 0) & ~init.is_lidar]
    r = np.linalg.norm(rand - centre, axis=1)
    inner, outer = r[: len(r) // 2], r[len(r) // 2 :]
    assert stats.kstest((inner / lidar_range) ** 3, "uniform").pvalue > 1e-3  # uniform in volume
    assert stats.kstest(1 / outer, "uniform", (1 / 1000.0, 1 / lidar_range - 1 / 1000.0)).pvalue > 1e-3
    assert np.all(rand[len(r) // 2 :, 2] >= centre[2])  # beyond the range: above the ground only
    # Scales: 20 % of the mean distance to the 3 nearest other points, the background among its own
    # points and the instance among its own (brute-force distances for a sample of rows).
    for group in (ids == 0, ids == 3):
        pts, scales = init.means[group], init.scales[group]
        rows = np.random.default_rng(0).choice(len(pts), 200, replace=False)
        d = cdist(pts[rows], pts)
        d[np.arange(200), rows] = np.inf  # not the point itself
        np.testing.assert_allclose(scales[rows], 0.2 * np.sort(d, axis=1)[:, :3].mean(1), rtol=1e-9)


def test_instance_cap_shares_the_lidar_budget():
    scene, tracks, _ground, load = _scene()
    cfg = InitConfig(max_lidar_points=300, points_per_lidar_point=0.0, seed=1)
    init = instance_initial_points(scene, tracks, cfg, load)
    assert np.sum(init.instance_ids == 3) == 150  # half of the cap
    assert np.sum(init.is_lidar) <= 300
