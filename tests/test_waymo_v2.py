"""The v2 parquet reader: same scene as v1 for the same data, the real vehicle_pose file, bad input."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from idsplat_ns.data.waymo import load_segment
from idsplat_ns.data.waymo.fixtures import write_synthetic_segment, write_v2_from_v1
from idsplat_ns.errors import IDSplatError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo"
FRAME = DATA / "pvps_data_one_frame.tfrecord"
POSES = DATA / "vehicle_pose_10023947602400723454_1120_000_1140_000.parquet"
CONTEXT = "1024360143612057520_3580_000_3600_000"
pytestmark = pytest.mark.skipif(not FRAME.is_file(), reason=f"real Waymo frame not found at {FRAME}")


@pytest.fixture(scope="module")
def v1_and_v2(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wv2")
    seg = write_synthetic_segment(FRAME, tmp / "seg.tfrecord", 4, top_width=200, side_shape=(20, 60), speed=8.0)
    root = tmp / "v2"
    assert write_v2_from_v1(seg, root) == CONTEXT
    return seg, root


def test_v1_and_v2_give_the_same_scene(v1_and_v2):
    seg, root = v1_and_v2
    a = load_segment(seg, cameras=["FRONT", "SIDE_RIGHT"], start=1, end=3)
    b = load_segment(root, cameras=["FRONT", "SIDE_RIGHT"], start=1, end=3, context_name=CONTEXT)
    assert a.frame_indices.tolist() == b.frame_indices.tolist() == [1, 2]
    assert np.array_equal(a.ego_poses, b.ego_poses) and np.array_equal(a.world_from_raw, b.world_from_raw)
    assert np.array_equal(a.frame_times, b.frame_times) and a.frame_times[1] == pytest.approx(0.1)
    for x, y in zip(a.images, b.images, strict=True):
        assert (x.camera, x.frame_index) == (y.camera, y.frame_index)
        assert x.intrinsics == y.intrinsics and np.array_equal(x.camera_to_world, y.camera_to_world)
        assert x.time == y.time and x.image_bytes == y.image_bytes
    for x, y in zip(a.lidar, b.lidar, strict=True):
        assert x.num_rays == y.num_rays > 0
        for name in ("origins", "directions", "ranges", "intensities", "times", "returned", "sensor_ids"):
            assert np.array_equal(getattr(x, name), getattr(y, name)), name
    ta = {t.track_id: t for t in a.tracks}
    tb = {t.track_id: t for t in b.tracks}
    assert ta.keys() == tb.keys() and len(ta) == 75
    for k in ta:
        assert np.allclose(ta[k].poses, tb[k].poses) and np.allclose(ta[k].size, tb[k].size)


def test_v2_root_can_be_the_split_folder(v1_and_v2):
    _, root = v1_and_v2
    s = load_segment(root / "training", cameras=["FRONT"], load_lidar=False, end=2)
    assert s.num_frames == 2 and not s.has_lidar


def test_v2_unknown_context_and_camera(v1_and_v2):
    _, root = v1_and_v2
    with pytest.raises(IDSplatError, match="no vehicle_pose/nope.parquet"):
        load_segment(root, context_name="nope")
    with pytest.raises(IDSplatError, match="no camera named REAR"):
        load_segment(root, context_name=CONTEXT, cameras=["REAR"])


def test_v2_corrupt_component(v1_and_v2, tmp_path):
    _, root = v1_and_v2
    bad = tmp_path / "v2"
    for comp in ("vehicle_pose", "camera_calibration", "camera_image"):
        (bad / comp).mkdir(parents=True)
        src = root / "training" / comp / f"{CONTEXT}.parquet"
        (bad / comp / src.name).write_bytes(src.read_bytes() if comp != "camera_image" else b"PAR1 garbage")
    with pytest.raises(IDSplatError) as info:
        load_segment(bad, context_name=CONTEXT, load_lidar=False)
    assert "camera_image" in str(info.value) and "not a readable parquet" in str(info.value)


@pytest.mark.skipif(not POSES.is_file(), reason=f"real v2 vehicle_pose file not found at {POSES}")
def test_real_vehicle_pose_component(v1_and_v2, tmp_path):
    """The shared real vehicle_pose parquet drives frame numbering and ego poses."""
    _, root = v1_and_v2
    context = POSES.stem.removeprefix("vehicle_pose_")
    base = tmp_path / "validation"
    (base / "vehicle_pose").mkdir(parents=True)
    os.symlink(POSES, base / "vehicle_pose" / f"{context}.parquet")
    real = pq.read_table(POSES)
    ts = np.sort(real.column("key.frame_timestamp_micros").to_numpy())
    # Camera calibration from the synthetic set, renamed to this context; tiny placeholder images.
    (base / "camera_calibration").mkdir()
    cal = pq.read_table(root / "training" / "camera_calibration" / f"{CONTEXT}.parquet")
    cal = cal.set_column(0, "key.segment_context_name", pa.array([context] * cal.num_rows))
    pq.write_table(cal, base / "camera_calibration" / f"{context}.parquet")
    (base / "camera_image").mkdir()
    eye = [float(v) for v in np.eye(4).reshape(-1)]
    I = "[CameraImageComponent]"
    pq.write_table(pa.table({
        "key.segment_context_name": [context] * len(ts), "key.frame_timestamp_micros": ts, "key.camera_name": [1] * len(ts),
        f"{I}.image": [b"\xff\xd8jpeg"] * len(ts), f"{I}.pose.transform": pa.array([eye] * len(ts), pa.list_(pa.float64(), 16)),
        f"{I}.pose_timestamp": ts * 1e-6, f"{I}.rolling_shutter_params.shutter": [0.003] * len(ts),
        f"{I}.rolling_shutter_params.camera_trigger_time": ts * 1e-6 - 0.02,
        f"{I}.rolling_shutter_params.camera_readout_done_time": ts * 1e-6 + 0.02,
    }), base / "camera_image" / f"{context}.parquet")

    s = load_segment(tmp_path, context_name=context, cameras=["FRONT"], start=10, end=15, load_lidar=False)
    assert len(ts) == 199 and s.frame_indices.tolist() == [10, 11, 12, 13, 14]
    assert s.frame_times == pytest.approx((ts[10:15] - ts[10]) * 1e-6)
    col = real.column("[VehiclePoseComponent].world_from_vehicle.transform").to_pylist()
    by_ts = dict(zip(real.column("key.frame_timestamp_micros").to_pylist(), col))
    raw = np.array([np.asarray(by_ts[t], np.float64).reshape(4, 4) for t in ts[10:15]])
    # A frame's vehicle pose is about mid-sweep (no lidar loaded: no pixel poses to say more), its
    # timestamp the sweep's start: the ego pose at frame k's time lies halfway between the frame
    # poses of k - 1 and k (frames 0.1 s apart), and the first one half a step before its own.
    assert s.metadata["frame_pose_times"] == pytest.approx(s.frame_times + 0.05)
    halfway = (raw[:-1, :3, 3] + raw[1:, :3, 3]) / 2 - raw[0, :3, 3]
    assert np.allclose(s.ego_poses[1:, :3, 3], halfway, atol=0.01)
    assert np.allclose(s.ego_poses[0, :3, 3], -(raw[1, :3, 3] - raw[0, :3, 3]) / 2, atol=0.01)
    assert np.allclose(s.ego_poses[:, :3, :3], raw[:, :3, :3], atol=0.01)  # a straight drive: hardly turning
    steps = np.linalg.norm(np.diff(s.ego_poses[:, :3, 3], axis=0), axis=1)
    assert np.all(steps < 3.0)  # <= 30 m/s between 0.1 s frames: a real driving trajectory
