"""A small hand-built scene for the instance tests: two cameras, a lidar, a moving and turning car
(a box), a parked car, the ground and a wall. Images are procedural textures (no renderer)."""

from __future__ import annotations

import numpy as np

from idsplat_ns.data.camera import CameraImage, Intrinsics
from idsplat_ns.data.geometry import make_pose, rot_z
from idsplat_ns.data.lidar import LidarSweep, rays_from_points
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import ObjectTrack

CAR_SIZE = np.array([4.5, 1.8, 1.5])
SENSOR = np.array([0.0, 0.0, 1.9])


def camera_pose(yaw: float, position=(0.0, 0.0, 1.5)) -> np.ndarray:
    """OpenCV camera looking along world +x rotated by ``yaw`` about z."""
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns: cam x, y, z in world
    return make_pose(rot_z(yaw) @ base, np.asarray(position))


def car_poses(num_frames: int, dt: float) -> np.ndarray:
    t = np.arange(num_frames) * dt
    yaw = 0.15 * t  # slowly turning
    pos = np.stack([12.0 + 6.0 * t, 1.0 + 0.5 * t**2, np.full_like(t, CAR_SIZE[2] / 2)], 1)
    return make_pose(rot_z(yaw), pos)


def box_surface(n: int, size: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points on the surface of a box centred at the origin (box frame)."""
    half = size / 2
    pts = rng.uniform(-1, 1, (n, 3)) * half
    face = rng.integers(0, 3, n)
    pts[np.arange(n), face] = np.sign(rng.uniform(-1, 1, n)) * half[face]
    return pts


def visible_from(points: np.ndarray, pose: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Points of a box surface facing the origin (back faces removed)."""
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    normal_local = np.zeros_like(local)
    half = CAR_SIZE / 2
    axis = np.argmax(np.abs(local) / half, 1)
    normal_local[np.arange(len(local)), axis] = np.sign(local[np.arange(len(local)), axis])
    normal = normal_local @ pose[:3, :3].T
    return np.sum(normal * (origin - points), 1) > 0


def body_features(local: np.ndarray, dim: int = 24, seed: int = 7) -> np.ndarray:
    """Smooth features of body-frame positions (random Fourier features): the same surface point
    has the same feature at every frame."""
    rng = np.random.default_rng(seed)
    W = rng.normal(scale=2.0, size=(3, dim))
    b = rng.uniform(0, 2 * np.pi, dim)
    return np.cos(local @ W + b).astype(np.float32)


def make_scene(num_frames: int = 6, dt: float = 0.1, seed: int = 0, width: int = 320, height: int = 200) -> Scene:
    rng = np.random.default_rng(seed)
    K = Intrinsics(fx=160.0, fy=160.0, cx=width / 2, cy=height / 2, width=width, height=height)
    cams = {"front_camera": camera_pose(0.0), "front_left_camera": camera_pose(np.radians(40.0))}
    moving = car_poses(num_frames, dt)
    parked = make_pose(np.eye(3), np.array([20.0, -6.0, CAR_SIZE[2] / 2]))
    images, sweeps = [], []
    for f in range(num_frames):
        t = f * dt
        for name, pose in cams.items():
            img = (rng.integers(0, 255, (height, width, 3))).astype(np.uint8)
            images.append(CameraImage(camera=name, frame_index=f, time=t, raw_timestamp=t, camera_to_world=pose,
                                      intrinsics=K, image=img))
        car_pts = box_surface(3000, CAR_SIZE, rng)
        world_car = car_pts @ moving[f, :3, :3].T + moving[f, :3, 3]
        world_car = world_car[visible_from(world_car, moving[f], SENSOR)]
        parked_pts = box_surface(1500, CAR_SIZE, rng) + parked[:3, 3]
        parked_pts = parked_pts[visible_from(parked_pts, parked, SENSOR)]
        ground = np.c_[rng.uniform(2, 60, 4000), rng.uniform(-15, 15, 4000), np.zeros(4000)]
        wall = np.c_[np.full(1500, 45.0), rng.uniform(-20, 20, 1500), rng.uniform(0, 6, 1500)]
        far = np.c_[rng.uniform(85, 95, 200), rng.uniform(-3, 3, 200), rng.uniform(0, 2, 200)]  # beyond 80 m
        pts = np.concatenate([world_car, parked_pts, ground, wall, far])
        origins = np.broadcast_to(SENSOR, pts.shape).copy()
        d, r = rays_from_points(origins, pts)
        n = len(pts)
        sweeps.append(LidarSweep(frame_index=f, time=t, raw_timestamp=t, sensor_to_world=make_pose(np.eye(3), SENSOR),
                                 origins=origins, directions=d, ranges=r, intensities=np.zeros(n, np.float32),
                                 times=np.full(n, t), returned=np.ones(n, bool), sensor_ids=np.zeros(n, np.int16)))
    tracks = [
        ObjectTrack("moving", "car", np.arange(num_frames), np.arange(num_frames) * dt, moving, CAR_SIZE, True),
        ObjectTrack("parked", "car", np.arange(num_frames), np.arange(num_frames) * dt,
                    np.repeat(parked[None], num_frames, 0), CAR_SIZE, False),
    ]
    return Scene(name="handmade", source="synthetic", root=None, frame_indices=np.arange(num_frames),
                 frame_times=np.arange(num_frames) * dt, ego_poses=np.repeat(np.eye(4)[None], num_frames, 0),
                 images=images, lidar=sweeps, tracks=tracks)
