"""The real Waymo frame through the v1 reader: cameras, calibration, labels and projection accuracy."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from idsplat_ns.data.waymo.projection_check import box_projection_errors
from idsplat_ns.data.waymo import load_segment
from idsplat_ns.data.waymo.calibration import WAYMO_FROM_OPENCV
from idsplat_ns.data.waymo.proto import build_file_descriptor
from idsplat_ns.data.waymo.proto.schema import to_proto_text
from idsplat_ns.errors import IDSplatError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo"
FRAME = DATA / "pvps_data_one_frame.tfrecord"
pytestmark = pytest.mark.skipif(not FRAME.is_file(), reason=f"real Waymo frame not found at {FRAME}")


@pytest.fixture(scope="module")
def scene():
    return load_segment(FRAME)


def test_cameras_sizes_and_calibration(scene):
    sizes = {im.camera: (im.intrinsics.width, im.intrinsics.height) for im in scene.images}
    assert sizes == {"FRONT": (1920, 1280), "FRONT_LEFT": (1920, 1280), "FRONT_RIGHT": (1920, 1280),
                     "SIDE_LEFT": (1920, 886), "SIDE_RIGHT": (1920, 886)}
    front = scene.images_of("FRONT")[0]
    assert front.intrinsics.fx == pytest.approx(2044.5083584358413)
    assert front.intrinsics.cy == pytest.approx(633.2422462156501)
    assert front.intrinsics.distortion[:2] == pytest.approx((0.040358363932006036, -0.33001662226602974))
    assert front.rolling_shutter.direction == "left_to_right"
    assert 0.0 < front.rolling_shutter.readout_seconds < 0.05
    assert len(front.image_bytes) == 446413 and front.image_bytes[:2] == b"\xff\xd8"  # JPEG kept encoded
    assert scene.metadata["protobuf_schema"].startswith(("idsplat schema", "waymo_open_dataset"))


def test_camera_axes_are_opencv(scene):
    # The FRONT camera looks along the vehicle's +x with image x to the vehicle's right (-y).
    front = scene.images_of("FRONT")[0]
    ego = scene.ego_poses[0]
    cam_in_vehicle = np.linalg.inv(ego) @ front.camera_to_world
    assert cam_in_vehicle[:3, 2] @ np.array([1.0, 0, 0]) > 0.99  # optical axis forward
    assert cam_in_vehicle[:3, 0] @ np.array([0, -1.0, 0]) > 0.99  # image x = right
    assert cam_in_vehicle[:3, 1] @ np.array([0, 0, -1.0]) > 0.99  # image y = down
    assert np.allclose(WAYMO_FROM_OPENCV[:3, :3] @ np.array([0, 0, 1.0]), [1, 0, 0])


def test_recentring_and_time(scene):
    assert np.allclose(scene.ego_poses[0][:3, 3], 0.0)
    assert np.allclose(scene.world_from_raw[:3, 3], [25211.2589, -42391.0813, 160.618], atol=1e-3)
    assert scene.frame_times.tolist() == [0.0] and scene.raw_time_unit_seconds == 1e-6
    assert scene.time_origin_raw == 1553735853462203
    # FRONT image pose timestamp is 1553735853.5146208 s, 52.4 ms after the frame start.
    assert scene.images_of("FRONT")[0].time == pytest.approx(0.0524178, abs=1e-5)


def test_laser_labels_become_tracks(scene):
    assert len(scene.tracks) == 75
    assert Counter(t.label for t in scene.tracks) == {"vehicle": 37, "pedestrian": 12, "sign": 25, "cyclist": 1}
    assert Counter(t.group for t in scene.tracks)["cyclist"] == 1
    first = next(t for t in scene.tracks if t.track_id == "-uZgRjAOvgiK1-0dUx_4Sg")
    assert first.size == pytest.approx([0.12923822353497522, 0.5820897280943128, 0.539999999999992])  # length, width, height
    assert first.num_lidar_points.tolist() == [46] and not first.moving
    vehicles = [t for t in scene.tracks if t.label == "vehicle"]
    assert np.median([t.size[0] / t.size[1] for t in vehicles]) > 1.5  # x (length) is the long side


def _projection_errors(scene, max_r2: float | None = None) -> np.ndarray:
    """|edge error| (px) of each box's projected corners vs Waymo's projected_lidar_labels."""
    out = []
    for im in scene.images:
        errors, r2 = box_projection_errors(im, scene.tracks)
        out.append(errors if max_r2 is None else errors[r2 <= max_r2])
    return np.concatenate(out)


def test_box_projection_matches_waymo_projected_labels(scene):
    errors = _projection_errors(scene)
    assert len(errors) >= 60
    assert np.median(errors) < 0.05  # measured 0.018 px
    assert np.percentile(errors, 90) < 0.2
    # Boxes whose corners stay where the distortion polynomial is monotonic (r^2 < 0.8 for these
    # lenses): every edge within a pixel. Beyond it the polynomial folds back (3 side-camera boxes).
    inside = _projection_errors(scene, max_r2=0.8)
    assert len(inside) >= 55 and inside.max() < 1.0


def test_camera_subset_and_downscale():
    s = load_segment(FRAME, cameras=["front", "SIDE_LEFT"], image_scale=0.5, load_lidar=False)
    assert [im.camera for im in s.images] == ["FRONT", "SIDE_LEFT"]
    front, side = s.images
    assert front.image.shape == (640, 960, 3) and front.image_bytes is None
    assert side.image.shape == (443, 960, 3)
    assert front.intrinsics.fx == pytest.approx(2044.5083584358413 / 2)
    assert 40 < front.image.mean() < 220


def test_missing_camera_is_one_line():
    with pytest.raises(IDSplatError) as info:
        load_segment(FRAME, cameras=["FRONT", "REAR"])
    msg = str(info.value)
    assert "\n" not in msg and str(FRAME) in msg and "REAR" in msg and "FRONT_LEFT" in msg


def test_start_beyond_the_segment():
    with pytest.raises(IDSplatError, match="no frame at index 3"):
        load_segment(FRAME, start=3)


def test_shipped_proto_text_matches_the_schema():
    shipped = Path(__file__).resolve().parents[1] / "idsplat_ns" / "data" / "waymo" / "proto" / "frame_subset.proto"
    assert shipped.read_text() == to_proto_text()
    fdp = build_file_descriptor()
    frame = next(m for m in fdp.message_type if m.name == "Frame")
    assert {f.name: f.number for f in frame.field}["projected_lidar_labels"] == 9
