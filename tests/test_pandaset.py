"""PandaSet parser against sequences written here by hand (not by the project's generator)."""

import gzip
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.errors import IDSplatError

OFFSET = np.array([446_000.0, 5_600_000.0, 35.0])  # UTM-like: must be recentred


def _pose_json(R, t):
    q = Rotation.from_matrix(R).as_quat()  # xyzw
    return {"position": dict(zip("xyz", map(float, t))), "heading": {"w": float(q[3]), "x": float(q[0]), "y": float(q[1]), "z": float(q[2])}}


def write_sequence(root: Path, num_frames: int = 3, cameras=("front_camera", "left_camera")) -> dict:
    """A minimal PandaSet sequence; returns what was written, in raw coordinates."""
    rng = np.random.default_rng(0)
    truth = {"lidar_t": [], "points": [], "cam_poses": {}, "lidar_poses": []}
    stamps = 1_557_540_000.0 + 0.1 * np.arange(num_frames)
    (root / "lidar").mkdir(parents=True)
    for f in range(num_frames):
        ego_t = OFFSET + np.array([0.8 * f, 0.1 * f, 0.0])
        R = Rotation.from_euler("z", 5 * f, degrees=True).as_matrix()
        truth["lidar_poses"].append((R, ego_t))
        pts = ego_t + rng.normal(size=(50, 3)) * [10, 10, 1]
        t = stamps[f] + np.sort(rng.uniform(-0.05, 0.05, 50))
        df = pd.DataFrame({"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "i": rng.uniform(0, 255, 50), "t": t,
                           "d": np.r_[np.zeros(40, int), np.ones(10, int)]})
        df.to_pickle(root / "lidar" / f"{f:02d}.pkl.gz")
        truth["points"].append(df)
    (root / "lidar" / "poses.json").write_text(json.dumps([_pose_json(R, t) for R, t in truth["lidar_poses"]]))
    (root / "lidar" / "timestamps.json").write_text(json.dumps(stamps.tolist()))
    for c, cam in enumerate(cameras):
        folder = root / "camera" / cam
        folder.mkdir(parents=True)
        poses = []
        for f in range(num_frames):
            R = Rotation.from_euler("zyx", [5 * f + 30 * c, 0, -90], degrees=True).as_matrix()
            poses.append((R, OFFSET + [0.8 * f, 0.1 * f, 1.6]))
            Image.fromarray(rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)).save(folder / f"{f:02d}.jpg")
        truth["cam_poses"][cam] = poses
        (folder / "poses.json").write_text(json.dumps([_pose_json(R, t) for R, t in poses]))
        (folder / "intrinsics.json").write_text(json.dumps({"fx": 30.0 + c, "fy": 31.0, "cx": 16.0, "cy": 12.0}))
        (folder / "timestamps.json").write_text(json.dumps((stamps + 0.01 * (c + 1)).tolist()))
    (root / "annotations" / "cuboids").mkdir(parents=True)
    for f in range(num_frames):
        rows = [
            # A car moving along +x with yaw -pi/2 (length axis along +x), and its PandarGT duplicate.
            {"uuid": "car-1", "label": "Car", "yaw": -np.pi / 2, "stationary": False, "camera_used": 0,
             "position.x": OFFSET[0] + 5 + 2 * f, "position.y": OFFSET[1] + 3, "position.z": OFFSET[2] + 0.8,
             "dimensions.x": 1.9, "dimensions.y": 4.5, "dimensions.z": 1.6, "attributes.object_motion": "Moving",
             "cuboids.sibling_id": "car-1-gt", "cuboids.sensor_id": 0},
            {"uuid": "car-1-gt", "label": "Car", "yaw": 0.0, "stationary": False, "camera_used": 0,
             "position.x": 0.0, "position.y": 0.0, "position.z": 0.0, "dimensions.x": 1, "dimensions.y": 1, "dimensions.z": 1,
             "attributes.object_motion": "Moving", "cuboids.sibling_id": "car-1", "cuboids.sensor_id": 1},
            {"uuid": "parked", "label": "Car", "yaw": 0.0, "stationary": True, "camera_used": -1,
             "position.x": OFFSET[0] - 5, "position.y": OFFSET[1] + 4, "position.z": OFFSET[2] + 0.8,
             "dimensions.x": 2.0, "dimensions.y": 4.0, "dimensions.z": 1.5, "attributes.object_motion": "Parked",
             "cuboids.sibling_id": "-", "cuboids.sensor_id": -1},
        ]
        pd.DataFrame(rows).to_pickle(root / "annotations" / "cuboids" / f"{f:02d}.pkl.gz")
    truth["stamps"] = stamps
    return truth


def test_round_trip_poses_points_times(tmp_path):
    truth = write_sequence(tmp_path / "001")
    scene = load_sequence(tmp_path / "001", lidar_sensors=(0, 1))
    origin_raw = truth["lidar_poses"][0][1]
    assert scene.source == "pandaset" and scene.num_frames == 3
    np.testing.assert_allclose(scene.ego_poses[0][:3, 3], 0.0, atol=1e-9)  # recentred on the first ego position
    np.testing.assert_allclose(scene.world_from_raw[:3, 3], -origin_raw)
    for f in range(3):
        R, t = truth["lidar_poses"][f]
        np.testing.assert_allclose(scene.ego_poses[f][:3, :3], R, atol=1e-9)
        np.testing.assert_allclose(scene.ego_poses[f][:3, 3], t - origin_raw, atol=1e-9)
    im = scene.images_of("left_camera")[2]
    R, t = truth["cam_poses"]["left_camera"][2]
    np.testing.assert_allclose(im.camera_to_world[:3, :3], R, atol=1e-9)
    np.testing.assert_allclose(im.camera_to_world[:3, 3], t - origin_raw, atol=1e-9)
    assert (im.intrinsics.fx, im.intrinsics.width, im.intrinsics.height) == (31.0, 32, 24)
    # Times: seconds from the earliest first-frame timestamp (the lidar's), float64.
    np.testing.assert_allclose(scene.frame_times, truth["stamps"] - truth["stamps"][0], atol=1e-9)
    assert im.time == pytest.approx(truth["stamps"][2] + 0.02 - truth["stamps"][0], abs=1e-9)
    for f, sweep in enumerate(scene.lidar):
        df = truth["points"][f]
        np.testing.assert_allclose(sweep.points, df[["x", "y", "z"]].to_numpy() - origin_raw, atol=1e-6)
        np.testing.assert_allclose(sweep.times, df["t"].to_numpy() - truth["stamps"][0], atol=1e-9)
        np.testing.assert_allclose(sweep.intensities, df["i"].to_numpy() / 255, atol=1e-6)
        assert sweep.returned.all() and sweep.sensor_ids.tolist() == df["d"].tolist()


def test_lidar_sensor_selection_and_ray_origins(tmp_path):
    truth = write_sequence(tmp_path / "002")
    scene = load_sequence(tmp_path / "002")  # default: the Pandar64 only
    sweep = scene.lidar[1]
    assert len(sweep.ranges) == 40 and (sweep.sensor_ids == 0).all()
    # Origins follow the sensor between sweeps: the ego position interpolated at each point's time.
    t_raw = truth["points"][1]["t"].to_numpy()[:40]
    stamps = truth["stamps"]
    ex = np.interp(t_raw, stamps, [p[1][0] for p in truth["lidar_poses"]]) - truth["lidar_poses"][0][1][0]
    np.testing.assert_allclose(sweep.origins[:, 0], ex, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(sweep.directions, axis=1), 1.0)


def test_cuboids_become_tracks(tmp_path):
    write_sequence(tmp_path / "003")
    scene = load_sequence(tmp_path / "003")
    tracks = {t.track_id: t for t in scene.tracks}
    assert set(tracks) == {"car-1", "parked"}  # the PandarGT duplicate is dropped
    car = tracks["car-1"]
    assert car.moving and not tracks["parked"].moving
    np.testing.assert_allclose(car.size, [4.5, 1.9, 1.6])  # length, width, height
    np.testing.assert_allclose(car.poses[0][:3, 0], [1, 0, 0], atol=1e-12)  # x along the length = direction of travel
    np.testing.assert_allclose(np.diff(car.poses[:, 0, 3]), 2.0)
    # 2 m per 0.1 s; unix-second stamps near 1.6e9 resolve ~2.4e-7 s in float64, hence rtol 1e-5.
    np.testing.assert_allclose(car.speeds, 20.0, rtol=1e-5)


def test_camera_and_frame_selection(tmp_path):
    write_sequence(tmp_path / "004")
    scene = load_sequence(tmp_path / "004", cameras=["left_camera"], start=1, end=3, load_lidar=False)
    assert scene.camera_names == ["left_camera"] and scene.frame_indices.tolist() == [1, 2]
    np.testing.assert_allclose(scene.ego_poses[0][:3, 3], 0.0, atol=1e-9)
    assert scene.frame_times[0] == pytest.approx(0.0)


def test_bad_input_is_one_line(tmp_path):
    with pytest.raises(IDSplatError, match="no such PandaSet sequence folder"):
        load_sequence(tmp_path / "missing")
    write_sequence(tmp_path / "005")
    with pytest.raises(IDSplatError, match="camera 'back_camera' not in this sequence"):
        load_sequence(tmp_path / "005", cameras=["back_camera"])
    pkl = tmp_path / "005" / "lidar" / "01.pkl.gz"
    data = pkl.read_bytes()
    pkl.write_bytes(data[: len(data) // 2])  # truncated download
    with pytest.raises(IDSplatError) as err:
        load_sequence(tmp_path / "005")
    assert "01.pkl.gz" in str(err.value) and "\n" not in str(err.value)
    with gzip.open(pkl, "wb") as fh:
        fh.write(b"not a pickle")
    with pytest.raises(IDSplatError, match="unreadable pickle"):
        load_sequence(tmp_path / "005")
    with pytest.raises(IDSplatError, match="outside the sequence"):
        load_sequence(tmp_path / "005", start=2, end=9, load_lidar=False)
