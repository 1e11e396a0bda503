"""Range-image decoding, checked on range images built in Waymo's exact format."""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from idsplat_ns.data.waymo import load_segment
from idsplat_ns.data.waymo.fixtures import pose_to_euler, write_synthetic_segment
from idsplat_ns.data.waymo.proto import OWN
from idsplat_ns.data.waymo.range_image import (
    column_fire_fractions,
    decode_compressed_matrix,
    encode_compressed_matrix,
    euler_to_rotmat,
    parse_matrix_float,
    range_image_rays,
    rays_to_range_image,
    row_inclinations,
    serialize_matrix_float,
)
from idsplat_ns.errors import IDSplatError

FRAME = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


def test_matrix_float_codec_agrees_with_protobuf():
    arr = np.random.default_rng(0).normal(size=(3, 5, 4)).astype(np.float32)
    msg = OWN["MatrixFloat"]()
    msg.data.extend(arr.reshape(-1).tolist())
    msg.shape.dims.extend(arr.shape)
    assert serialize_matrix_float(arr) == msg.SerializeToString()
    assert np.array_equal(parse_matrix_float(msg.SerializeToString()), arr)
    back = OWN["MatrixFloat"]()
    back.ParseFromString(zlib.decompress(encode_compressed_matrix(arr)))
    assert list(back.shape.dims) == [3, 5, 4]


def test_corrupt_range_image_is_one_line():
    with pytest.raises(IDSplatError, match="frame 3 lidar TOP: corrupt"):
        decode_compressed_matrix(b"not zlib", "frame 3 lidar TOP")


def test_inclinations_top_row_first():
    incl = row_inclinations(4, None, -0.4, 0.0)
    assert incl == pytest.approx([-0.05, -0.15, -0.25, -0.35])  # uniform row centres, reversed
    assert row_inclinations(3, np.array([-0.3, -0.1, 0.05]), 0, 0) == pytest.approx([0.05, -0.1, -0.3])


def _extrinsic(yaw: float, t=(1.4, 0.1, 2.1)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    T[:3, 3] = t
    return T


def test_round_trip_points_range_image_rays():
    """Points on pixel directions -> range image -> decoder -> the same points (float32 range)."""
    rng = np.random.default_rng(3)
    H, W = 16, 120
    incl = np.sort(rng.uniform(-0.3, 0.05, H))[::-1]  # non-uniform, top row first
    extr = _extrinsic(0.0123)
    # Independent construction of each pixel's direction: spherical angles at pixel centres.
    az_corr = np.arctan2(extr[1, 0], extr[0, 0])
    az = np.pi - (np.arange(W) + 0.5) / W * 2 * np.pi - az_corr
    rows, cols = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    keep = rng.random((H, W)) < 0.8
    r = rng.uniform(2.0, 80.0, (H, W))
    d = np.stack([np.cos(az[cols]) * np.cos(incl[rows]), np.sin(az[cols]) * np.cos(incl[rows]), np.sin(incl[rows])], -1)
    points_lidar = (d * r[..., None])[keep]
    image = rays_to_range_image(points_lidar, incl, W, extr)
    assert np.array_equal(image[..., 0] > 0, keep)
    pose = _extrinsic(0.7, (100.0, -50.0, 3.0))
    origins, directions, ranges, returned = range_image_rays(image[..., 0], extr, incl, pose)
    assert np.array_equal(returned, keep.reshape(-1))
    world = origins[returned] + directions[returned] * ranges[returned, None]
    expected = (points_lidar @ extr[:3, :3].T + extr[:3, 3]) @ pose[:3, :3].T + pose[:3, 3]
    assert np.abs(world - expected).max() < 1e-5 * 80 + 1e-9  # float32 range quantisation
    assert np.all(ranges[~returned] == 0)


def test_pixel_pose_gives_each_ray_its_own_origin():
    rng = np.random.default_rng(4)
    H, W = 8, 40
    incl = np.linspace(0.05, -0.3, H)
    extr = _extrinsic(0.0)
    ranges = rng.uniform(5, 50, (H, W))
    pix = np.zeros((H, W, 6))
    pix[..., 0], pix[..., 1], pix[..., 2] = 0.01, -0.02, rng.uniform(-3, 3, (H, W))
    pix[..., 3] = np.linspace(0, 1, W)[None, :]
    origins, directions, rr, _ = range_image_rays(ranges, extr, incl, np.eye(4), pix)
    R = Rotation.from_euler("ZYX", np.stack([pix[..., 2], pix[..., 1], pix[..., 0]], -1).reshape(-1, 3)).as_matrix()
    assert np.allclose(euler_to_rotmat(pix[..., 0], pix[..., 1], pix[..., 2]).reshape(-1, 3, 3), R)
    assert np.allclose(origins, np.einsum("nij,j->ni", R, extr[:3, 3]) + pix[..., 3:6].reshape(-1, 3))
    assert np.allclose(np.linalg.norm(directions, axis=1), 1.0)
    roll, pitch, yaw = pose_to_euler(R[5])
    assert np.allclose(euler_to_rotmat(roll, pitch, yaw), R[5])


def test_fire_order_recovered_from_pixel_pose():
    W = 50
    yaw = 0.8
    frac_true = ((np.arange(W) - 20) % W + 0.5) / W  # sweep starts at column 20, left to right
    pix = np.zeros((2, W, 6))
    pix[..., 2] = yaw
    pix[..., 3:6] = (np.array([np.cos(yaw), np.sin(yaw), 0.0]) * frac_true[:, None] * 1.5)[None]
    assert np.allclose(column_fire_fractions(pix, W), frac_true)
    reversed_pix = pix[:, ::-1].copy()  # firing right to left
    assert np.allclose(column_fire_fractions(reversed_pix, W), frac_true[::-1])
    assert np.allclose(column_fire_fractions(np.zeros((2, W, 6)), W), (np.arange(W) + 0.5) / W)


@pytest.mark.skipif(not FRAME.is_file(), reason=f"real Waymo frame not found at {FRAME}")
def test_segment_lidar_rays(tmp_path):
    path = write_synthetic_segment(FRAME, tmp_path / "seg.tfrecord", 2, top_width=300, speed=10.0)
    scene = load_segment(path, cameras=["FRONT"], lidars=["TOP", "FRONT"])
    sweep = scene.lidar[1]
    top = sweep.sensor_ids == 1
    first = sweep.metadata["return_index"] == 1
    assert int((top & first).sum()) == 64 * 300  # every first-return pixel kept, hit or not
    assert 0.05 < 1 - sweep.returned[top & first].mean() < 0.15  # ~10 % no return, flagged
    assert np.all(sweep.returned[sweep.metadata["return_index"] == 2])
    assert np.all((sweep.intensities >= 0) & (sweep.intensities < 1))
    # TOP rays fire over the sweep: times span 0.1 s after the frame start, origins move with the ego
    t = sweep.times[top]
    assert t.min() == pytest.approx(0.1 + 0.05 / 300, abs=1e-6) and t.max() == pytest.approx(0.2 - 0.05 / 300, abs=1e-6)
    o = sweep.origins[top & first]
    late, early = o[np.argmax(sweep.times[top & first])], o[np.argmin(sweep.times[top & first])]
    heading = scene.ego_poses[1][:3, 0]
    assert (late - early) @ heading == pytest.approx(10.0 * 0.1 * (1 - 1 / 300), abs=0.01)
    # Sensor origins sit at the TOP lidar's mounting height above the ego origin.
    assert np.median(o[:, 2] - scene.ego_poses[1][2, 3]) == pytest.approx(2.18, abs=0.2)
    assert set(np.unique(sweep.sensor_ids)) == {1, 2}


@pytest.mark.skipif(not FRAME.is_file(), reason=f"real Waymo frame not found at {FRAME}")
@pytest.mark.parametrize("pose_fraction", [0.5, 0.3])
def test_each_ego_pose_is_stamped_with_its_own_time(tmp_path, pose_fraction):
    """A segment whose frame poses are the ego at ``pose_fraction`` of the sweep, while the frame
    timestamps are the sweeps' starts: the pixel poses give each frame pose its time, and the ego
    pose of a frame is where the ego was at the frame's timestamp (10 m/s: 1 m per 0.1 s)."""
    from idsplat_ns.data.waymo.range_image import pose_sweep_fraction

    path = write_synthetic_segment(FRAME, tmp_path / "seg.tfrecord", 3, top_width=300, speed=10.0,
                                   pose_fraction=pose_fraction)
    scene = load_segment(path, cameras=["FRONT"], lidars=["TOP"])
    assert scene.metadata["frame_pose_times"] == pytest.approx(scene.frame_times + pose_fraction * 0.1, abs=1e-3)
    # Recentring puts the first frame pose, the ego at time 0.1 * pose_fraction, at the origin.
    heading = scene.ego_poses[0][:3, 0]
    extrinsics = []
    for k in range(3):
        expected = heading * 10.0 * (0.1 * k - 0.1 * pose_fraction)
        assert np.allclose(scene.ego_poses[k][:3, 3], expected, atol=0.005), (k, scene.ego_poses[k][:3, 3], expected)
        extrinsics.append(np.linalg.inv(scene.ego_poses[k]) @ scene.lidar[k].sensor_to_world)
    # The lidar's pose of each sweep is the vehicle's at the sweep's time times the TOP extrinsic.
    assert np.allclose(extrinsics[0], extrinsics[1]) and np.allclose(extrinsics[0], extrinsics[2])
    # Standing still, or without pixel poses, the frame pose is taken at mid-sweep.
    assert pose_sweep_fraction(None, np.zeros(3)) == 0.5
    assert pose_sweep_fraction(np.zeros((2, 8, 6)), np.zeros(3)) == 0.5
