"""Rolling shutter on the data side: camera paths and velocities, projection into rolling-shutter
images (closed forms), the lifting stage, the built-in street's rolling-shutter option and the
PandaSet reader, and the render-time lookup of an image's shutter."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from idsplat_ns.data.camera import CameraImage, Intrinsics, RollingShutter
from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.data.lidar import LidarSweep, rays_from_points
from idsplat_ns.data.rolling_shutter import CameraPath, camera_paths, project_rolling
from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError

# OpenCV camera looking along world +x: camera x = world -y, camera y = world -z, camera z = world x.
BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
W, H, F = 160, 120, 100.0
INTR = Intrinsics(fx=F, fy=F, cx=W / 2, cy=H / 2, width=W, height=H)


def _sideways_camera(speed: float, shutter: RollingShutter, times=(0.0, 0.1, 0.2)) -> list[CameraImage]:
    """A camera translating along its own +x axis (world -y) at ``speed`` m/s."""
    return [CameraImage(camera="cam", frame_index=k, time=t, raw_timestamp=t,
                        camera_to_world=make_pose(BASE, np.array([0.0, -speed * t, 1.5])), intrinsics=INTR,
                        image=np.zeros((H, W, 3), np.uint8), rolling_shutter=shutter) for k, t in enumerate(times)]


def _camera_coords_to_world(xyz: np.ndarray, image: CameraImage) -> np.ndarray:
    return xyz @ image.camera_to_world[:3, :3].T + image.camera_to_world[:3, 3]


def test_camera_path_velocity_is_the_constant_motion():
    # Moving at v while yawing at w: the central difference is exact for this motion.
    v, w = np.array([3.0, -1.0, 0.5]), 0.4
    times = np.arange(6) * 0.1
    poses = np.stack([make_pose(rot_z(w * t) @ BASE, v * t) for t in times])
    path = CameraPath(times, poses)
    for t in (0.0, 0.23, 0.5):  # an end, between samples, the other end
        lin, ang = path.velocity_at(t)
        np.testing.assert_allclose(lin, v, atol=1e-9)
        np.testing.assert_allclose(ang, [0.0, 0.0, w], atol=1e-9)
    np.testing.assert_allclose(path.pose_at(0.25), make_pose(rot_z(w * 0.25) @ BASE, v * 0.25), atol=1e-12)
    lin, ang = CameraPath(times[:1], poses[:1]).velocity_at(0.0)
    assert not lin.any() and not ang.any()


@pytest.mark.parametrize("direction", ["top_to_bottom", "left_to_right"])
def test_points_project_with_the_pose_of_their_own_line(direction):
    # Camera moving along its x axis at s m/s. Top-to-bottom: the row is unchanged and
    # u = f (X - s tau(v)) / Z + cx. Left-to-right: u = f (X - s tau(u)) / Z + cx, linear in u.
    s, R = 20.0, 0.06
    image = _sideways_camera(s, RollingShutter(R, direction))[1]
    path = camera_paths(_sideways_camera(s, RollingShutter(R, direction)))["cam"]
    rng = np.random.default_rng(0)
    cam_xyz = np.c_[rng.uniform(-3, 3, 50), rng.uniform(-2, 2, 50), rng.uniform(6, 20, 50)]
    proj, tau = project_rolling(_camera_coords_to_world(cam_xyz, image), image, path)
    X, Y, Z = cam_xyz.T
    v = F * Y / Z + H / 2
    if direction == "top_to_bottom":
        expect_tau = (v - H / 2) / (H - 1) * R
        u = F * (X - s * expect_tau) / Z + W / 2
    else:  # tau = a + b u with a = -R/2 W/(W-1), b = R/(W-1)
        a, b = -R / 2 * W / (W - 1), R / (W - 1)
        u = (F * (X - s * a) / Z + W / 2) / (1 + F * s * b / Z)
        expect_tau = a + b * u
    inside = (u > 0) & (u < W) & (v > 0) & (v < H)
    np.testing.assert_allclose(proj.uv[inside], np.c_[u, v][inside], atol=1e-6)
    np.testing.assert_allclose(tau[inside], expect_tau[inside], atol=1e-10)
    assert np.abs(proj.uv[inside, 0] - image.project(_camera_coords_to_world(cam_xyz, image)).uv[inside, 0]).max() > 3
    # A global-shutter image gives the plain projection.
    flat = dataclasses.replace(image, rolling_shutter=RollingShutter(0.0, direction))
    p0, t0 = project_rolling(_camera_coords_to_world(cam_xyz, image), flat, path)
    np.testing.assert_array_equal(p0.uv, flat.project(_camera_coords_to_world(cam_xyz, image)).uv)
    assert not t0.any()


def test_lifting_paints_points_through_the_rolling_shutter(tmp_path: Path):
    # A small static patch low in the image (late rows): its mask is where the rolling-shutter
    # camera saw it, ~10 px away from the global-shutter projection.
    from idsplat_ns.data.images import write_instance_map
    from idsplat_ns.instances.lifting import LiftingConfig, lift_instances
    from idsplat_ns.instances.masks.base import InstanceMaskSet, mask_filename

    s, R = 20.0, 0.06
    images = _sideways_camera(s, RollingShutter(R, "top_to_bottom"))
    rng = np.random.default_rng(1)
    cam_xyz = np.c_[rng.uniform(-0.05, 0.05, 60), rng.uniform(3.0, 3.2, 60), np.full(60, 10.0)]
    sweeps = []
    for k, im in enumerate(images):
        pts = _camera_coords_to_world(cam_xyz, im)
        origins = np.broadcast_to(im.camera_to_world[:3, 3], pts.shape).copy()
        d, r = rays_from_points(origins, pts)
        n = len(pts)
        sweeps.append(LidarSweep(frame_index=k, time=im.time, raw_timestamp=im.time, sensor_to_world=im.camera_to_world,
                                 origins=origins, directions=d, ranges=r, intensities=np.zeros(n, np.float32),
                                 times=np.full(n, im.time), returned=np.ones(n, bool), sensor_ids=np.zeros(n, np.int16)))
        X, Y, Z = cam_xyz.T
        v = F * Y / Z + H / 2
        u = F * (X - s * (v - H / 2) / (H - 1) * R) / Z + W / 2
        mask = np.zeros((H, W), np.uint16)
        mask[int(v.min()) - 1 : int(v.max()) + 2, int(u.min()) - 1 : int(u.max()) + 2] = 1
        write_instance_map(tmp_path / mask_filename("cam", k), mask)
    scene = Scene(name="rs", source="synthetic", root=None, frame_indices=np.arange(3), frame_times=np.array([0.0, 0.1, 0.2]),
                  ego_poses=np.stack([im.camera_to_world for im in images]), images=images, lidar=sweeps)
    masks = InstanceMaskSet(root=tmp_path, labels={1: "car"}, source="precomputed")
    config = LiftingConfig(erosion_px=0, use_dbscan=False, min_points=5)
    lifted = lift_instances(scene, masks, config, progress=False)
    assert [len(o.points) for o in lifted.observations[1]] == [60, 60, 60]
    np.testing.assert_array_equal(lifted.observations[1][1].times, np.full(60, 0.1))  # the points' own lidar time
    off = lift_instances(scene, masks, dataclasses.replace(config, rolling_shutter=False), progress=False)
    assert sum(len(o.points) for o in off.observations.get(1, [])) == 0


def test_painted_pixels_stay_inside_the_image_in_float32(tmp_path: Path):
    # u = W - 1e-6 is inside in float64 but rounds to W in float32, outside any descriptor's image.
    from idsplat_ns.data.images import write_instance_map
    from idsplat_ns.instances.lifting import LiftingConfig, paint_points
    from idsplat_ns.instances.masks.base import InstanceMaskSet, mask_filename

    image = _sideways_camera(0.0, None, times=(0.0,))[0]
    Z = 10.0
    cam_xyz = np.array([[(W - 1e-6 - W / 2) * Z / F, 0.1 * k, Z] for k in range(12)])
    pts = _camera_coords_to_world(cam_xyz, image)
    origins = np.broadcast_to(image.camera_to_world[:3, 3], pts.shape).copy()
    d, r = rays_from_points(origins, pts)
    n = len(pts)
    sweep = LidarSweep(frame_index=0, time=0.0, raw_timestamp=0.0, sensor_to_world=image.camera_to_world,
                       origins=origins, directions=d, ranges=r, intensities=np.zeros(n, np.float32),
                       times=np.zeros(n), returned=np.ones(n, bool), sensor_ids=np.zeros(n, np.int16))
    write_instance_map(tmp_path / mask_filename("cam", 0), np.ones((H, W), np.uint16))
    scene = Scene(name="edge", source="synthetic", root=None, frame_indices=np.arange(1), frame_times=np.zeros(1),
                  ego_poses=image.camera_to_world[None], images=[image], lidar=[sweep])
    painted, _, _ = paint_points(scene, InstanceMaskSet(tmp_path, {1: "car"}, "precomputed"), LiftingConfig(erosion_px=0),
                                 progress=False)
    uv = painted[0][1][0][2]
    assert len(uv) == 12 and uv.dtype == np.float32 and (uv[:, 0] < W).all()


def _rs_config(frames: int = 2, readout: float = 0.04, direction: str = "top_to_bottom"):
    from idsplat_ns.data.synthetic import get_preset

    tiny = get_preset("tiny")
    rig = dataclasses.replace(tiny.cameras, rolling_shutter_seconds=readout, rolling_shutter_direction=direction)
    return dataclasses.replace(tiny, name=f"tiny_rs{frames}", num_frames=frames, cameras=rig)


@pytest.mark.parametrize("direction", ["top_to_bottom", "right_to_left"])
def test_synthetic_rolling_shutter_lines_are_global_renders_at_their_times(direction):
    # Each line of the rolling-shutter image is that line of a global-shutter render made at the
    # line's time (an independent path: the camera pose and the road users at that time).
    from idsplat_ns.data.rolling_shutter import line_times
    from idsplat_ns.data.synthetic.camera_render import render_camera
    from idsplat_ns.data.synthetic.raycast import RayCaster
    from idsplat_ns.data.synthetic.rig import cameras
    from idsplat_ns.data.synthetic.world import build_world

    config = _rs_config(direction=direction)
    caster = RayCaster(build_world(config, 0))
    cam = cameras(config)[0]
    shutter = RollingShutter(0.04, direction)
    t = 0.45
    image, inst, _ = render_camera(caster, cam, t, 1, False, shutter)
    axis, tau = line_times(shutter, cam.width, cam.height)
    glob, glob_inst, _ = render_camera(caster, cam, t, 1, False)
    assert (image.astype(int) - glob).any() and np.abs(tau).max() == pytest.approx(0.02)
    for line in (0, cam.height // 3 if axis == 1 else cam.width // 3, (cam.height if axis == 1 else cam.width) - 1):
        ref, ref_inst, _ = render_camera(caster, cam, t + tau[line], 1, False)
        take = (lambda a: a[line]) if axis == 1 else (lambda a: a[:, line])
        assert np.abs(take(image).astype(int) - take(ref)).max() <= 1  # same rays; rounding at most
        np.testing.assert_array_equal(take(inst), take(ref_inst))


def test_synthetic_street_with_rolling_shutter_is_read_back(tmp_path: Path):
    from idsplat_ns.data.pandaset import load_sequence
    from idsplat_ns.data.synthetic import generate_sequence
    from idsplat_ns.data.synthetic.cli import config_from_args
    from idsplat_ns.data.synthetic.config import config_to_dict
    from idsplat_ns.model.camera_shutter import ShutterLookup

    # The option names its own street; without it the preset (and its generator.json) is unchanged.
    assert config_from_args("tiny", None, None, 40.0).name == "tiny_rs40"
    assert config_from_args("tiny", None, None, 40.0, "left_to_right").cameras.rolling_shutter_direction == "left_to_right"
    assert "rolling_shutter_seconds" not in config_to_dict(config_from_args("tiny", None, None))["cameras"]
    with pytest.raises(IDSplatError, match="--rolling-shutter-ms"):
        config_from_args("tiny", None, None, 150.0)

    seq = generate_sequence(tmp_path, _rs_config(frames=2), seed=0, progress=False)
    stored = json.loads((seq / "idsplat_extras" / "rolling_shutter.json").read_text())
    assert stored["front_camera"] == {"readout_seconds": 0.04, "direction": "top_to_bottom"}
    scene = load_sequence(seq)
    assert all(im.rolling_shutter == RollingShutter(0.04, "top_to_bottom") for im in scene.images)
    # The render-time lookup: the camera moves with the ego, 8 m/s along the street (world yaw 21 deg).
    lookup = ShutterLookup(scene.images, scene.camera_names)
    im = scene.images[1]
    found = lookup.at(scene.camera_names.index(im.camera), im.time)
    yaw = np.radians(21.0)
    np.testing.assert_allclose(found.linear_velocity, [8 * np.cos(yaw), 8 * np.sin(yaw), 0.0], atol=1e-4)
    np.testing.assert_allclose(found.angular_velocity, 0.0, atol=1e-6)
    assert lookup.at(0, im.time + 0.03) is None  # not an image's time: global

    # PandaSet proper has no such file; a damaged one is one line naming it.
    bad = tmp_path / "bad"
    shutil.copytree(seq, bad)
    (bad / "idsplat_extras" / "rolling_shutter.json").write_text('{"front_camera": {"readout_seconds": -1, "direction": "up"}}')
    with pytest.raises(IDSplatError, match="rolling_shutter.json"):
        load_sequence(bad)
    (bad / "idsplat_extras" / "rolling_shutter.json").unlink()
    assert all(im.rolling_shutter is None for im in load_sequence(bad).images)
