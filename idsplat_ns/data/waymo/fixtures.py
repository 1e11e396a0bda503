"""Waymo-format data built from a real frame, for tests and benchmarks (no real lidar is shipped).

- :func:`synthetic_range_images` makes range images (both returns, intensities, TOP per-pixel
  poses of a moving ego) in Waymo's exact encoding.
- :func:`write_synthetic_segment` re-frames a real v1 frame into an N-frame segment: the ego drives
  forward at constant speed, timestamps advance 0.1 s per frame, each frame gets fresh lidar.
- :func:`write_v2_from_v1` writes the same frames in the v2 parquet layout with Waymo's column names.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional

import numpy as np

from idsplat_ns.data.waymo import proto
from idsplat_ns.data.waymo.range_image import SWEEP_SECONDS, decode_compressed_matrix, encode_compressed_matrix
from idsplat_ns.data.waymo.records import LASER_NAMES
from idsplat_ns.data.waymo.tfrecord import iter_records, write_records

_LASER_NUMBER = {name: number for number, name in LASER_NAMES.items()}


def pose_to_euler(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return float(np.arctan2(R[2, 1], R[2, 2])), float(-np.arcsin(np.clip(R[2, 0], -1, 1))), float(np.arctan2(R[1, 0], R[0, 0]))


def synthetic_range_images(
    height: int,
    width: int,
    rng: np.random.Generator,
    vehicle_pose: Optional[np.ndarray] = None,  # [4, 4] vehicle-to-world at mid-sweep, for the TOP pixel pose
    speed: float = 10.0,
    no_return_fraction: float = 0.1,
    pose_fraction: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, Optional[np.ndarray]]:
    """Return 1 [H, W, 4], return 2 [H, W, 4] and (with ``vehicle_pose``) the pixel pose [H, W, 6].

    Ranges are smooth along rows (like a real scene) with holes of no return (-1). The pixel pose
    moves the ego forward along its heading, columns firing left to right over one sweep;
    ``vehicle_pose`` is where the ego is at ``pose_fraction`` of the sweep (Waymo: about 0.5).
    """
    cols = np.linspace(0, 2 * np.pi, width, endpoint=False)
    base = 5.0 + 60.0 * (0.5 + 0.5 * np.sin(cols[None, :] * 3 + np.arange(height)[:, None] * 0.05))
    r1 = np.zeros((height, width, 4), np.float32)
    r1[..., 0] = base + rng.normal(0, 0.05, (height, width))
    r1[..., 1] = rng.uniform(0, 1.5, (height, width))
    r1[..., 2] = rng.uniform(0, 0.5, (height, width))
    r1[rng.random((height, width)) < no_return_fraction, 0] = -1.0
    r2 = np.full((height, width, 4), 0.0, np.float32)
    r2[..., 0] = -1.0
    second = (rng.random((height, width)) < 0.05) & (r1[..., 0] > 0)
    r2[second, 0] = r1[second, 0] + rng.uniform(0.5, 5.0, int(second.sum()))
    r2[second, 1] = rng.uniform(0, 1, int(second.sum()))
    pose = None
    if vehicle_pose is not None:
        roll, pitch, yaw = pose_to_euler(vehicle_pose[:3, :3])
        frac = (np.arange(width) + 0.5) / width
        heading = vehicle_pose[:3, 0]
        trans = vehicle_pose[:3, 3][None, :] + heading[None, :] * speed * (frac[:, None] - pose_fraction) * SWEEP_SECONDS
        pose = np.zeros((height, width, 6), np.float32)
        pose[..., 0], pose[..., 1], pose[..., 2] = roll, pitch, yaw
        pose[..., 3:6] = trans[None, :, :]
    return r1, r2, pose


def add_lidar(frame, rng: np.random.Generator, top_width: int = 2650, side_shape: tuple[int, int] = (200, 600),
              speed: float = 10.0, pose_fraction: float = 0.5) -> None:
    """Fill ``frame.lasers`` (all calibrated lidars) with synthetic range images, in place."""
    del frame.lasers[:]
    pose = np.asarray(frame.pose.transform, dtype=np.float64).reshape(4, 4)
    for lc in frame.context.laser_calibrations:
        name = LASER_NAMES[int(lc.name)]
        h, w = (len(lc.beam_inclinations), top_width) if name == "TOP" else side_shape
        r1, r2, pixel_pose = synthetic_range_images(h, w, rng, pose if name == "TOP" else None, speed=speed,
                                                    pose_fraction=pose_fraction)
        laser = frame.lasers.add()
        laser.name = int(lc.name)
        laser.ri_return1.range_image_compressed = encode_compressed_matrix(r1, 1)
        laser.ri_return2.range_image_compressed = encode_compressed_matrix(r2, 1)
        if pixel_pose is not None:
            laser.ri_return1.range_image_pose_compressed = encode_compressed_matrix(pixel_pose, 1)


def synthetic_frames(
    source: str | Path,
    num_frames: int,
    with_lidar: bool = True,
    speed: float = 10.0,
    seed: int = 0,
    top_width: int = 2650,
    side_shape: tuple[int, int] = (200, 600),
    pose_fraction: float = 0.5,
) -> Iterator[bytes]:
    """Serialized frames: the first record of ``source`` moved forward by ``speed`` m/s per 0.1 s;
    each frame's pose is the ego at ``pose_fraction`` of its sweep (per the TOP pixel poses)."""
    (_, data), = list(iter_records(source, 0, 1))
    rng = np.random.default_rng(seed)
    for k in range(num_frames):
        frame = proto.Frame()
        frame.ParseFromString(data)
        dt = k * SWEEP_SECONDS
        pose = np.asarray(frame.pose.transform, dtype=np.float64).reshape(4, 4)
        shift = pose[:3, 0] * speed * dt
        frame.timestamp_micros += int(round(dt * 1e6))
        pose[:3, 3] += shift
        del frame.pose.transform[:]
        frame.pose.transform.extend(pose.reshape(-1).tolist())
        for im in frame.images:
            ip = np.asarray(im.pose.transform, dtype=np.float64).reshape(4, 4)
            ip[:3, 3] += shift
            del im.pose.transform[:]
            im.pose.transform.extend(ip.reshape(-1).tolist())
            im.pose_timestamp += dt
            im.camera_trigger_time += dt
            im.camera_readout_done_time += dt
        if with_lidar:
            add_lidar(frame, rng, top_width=top_width, side_shape=side_shape, speed=speed, pose_fraction=pose_fraction)
        yield frame.SerializeToString()


def write_synthetic_segment(source: str | Path, out: str | Path, num_frames: int, **kwargs) -> Path:
    """Write :func:`synthetic_frames` as a v1 TFRecord segment; returns its path."""
    write_records(out, synthetic_frames(source, num_frames, **kwargs))
    return Path(out)


def write_synthetic_frames_to(source: str | Path, out: str | Path, num_frames: int, progress=None, **kwargs) -> Path:
    """:func:`write_synthetic_segment` with an optional progress wrapper (e.g. ``tqdm``)."""
    frames = synthetic_frames(source, num_frames, **kwargs)
    if progress is not None:
        frames = progress(frames, total=num_frames, desc="writing synthetic segment", unit="frame")
    write_records(out, frames)
    return Path(out)


def write_v2_from_v1(tfrecord: str | Path, root: str | Path, split: str = "training") -> str:
    """Write a v1 segment's frames as v2 components under ``root/split``; returns the context name."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows: dict[str, list[dict]] = {k: [] for k in
                                   ("vehicle_pose", "camera_image", "camera_calibration", "lidar", "lidar_calibration", "lidar_pose", "lidar_box")}
    context = None
    for ref, data in iter_records(tfrecord):
        f = proto.Frame()
        f.ParseFromString(data)
        ctx = f.context.name
        ts = int(f.timestamp_micros)
        key = {"key.segment_context_name": ctx, "key.frame_timestamp_micros": ts}
        rows["vehicle_pose"].append({**key, "[VehiclePoseComponent].world_from_vehicle.transform": list(f.pose.transform)})
        for im in f.images:
            I = "[CameraImageComponent]"
            rows["camera_image"].append({**key, "key.camera_name": int(im.name), f"{I}.image": bytes(im.image),
                                         f"{I}.pose.transform": list(im.pose.transform), f"{I}.pose_timestamp": im.pose_timestamp,
                                         f"{I}.rolling_shutter_params.shutter": im.shutter,
                                         f"{I}.rolling_shutter_params.camera_trigger_time": im.camera_trigger_time,
                                         f"{I}.rolling_shutter_params.camera_readout_done_time": im.camera_readout_done_time})
        for laser in f.lasers:
            if not laser.ri_return1.range_image_compressed:
                continue
            R = "[LiDARComponent]"
            r1 = decode_compressed_matrix(laser.ri_return1.range_image_compressed, "r1")
            r2 = decode_compressed_matrix(laser.ri_return2.range_image_compressed, "r2")
            rows["lidar"].append({**key, "key.laser_name": int(laser.name),
                                  f"{R}.range_image_return1.values": r1.reshape(-1).tolist(), f"{R}.range_image_return1.shape": list(r1.shape),
                                  f"{R}.range_image_return2.values": r2.reshape(-1).tolist(), f"{R}.range_image_return2.shape": list(r2.shape)})
            if laser.ri_return1.range_image_pose_compressed:
                p = decode_compressed_matrix(laser.ri_return1.range_image_pose_compressed, "pose")
                rows["lidar_pose"].append({**key, "key.laser_name": int(laser.name),
                                           "[LiDARPoseComponent].range_image_return1.values": p.reshape(-1).tolist(),
                                           "[LiDARPoseComponent].range_image_return1.shape": list(p.shape)})
        for lb in f.laser_labels:
            B, b, m = "[LiDARBoxComponent]", lb.box, lb.metadata
            rows["lidar_box"].append({**key, "key.laser_object_id": lb.id,
                                      f"{B}.box.center.x": b.center_x, f"{B}.box.center.y": b.center_y, f"{B}.box.center.z": b.center_z,
                                      f"{B}.box.size.x": b.length, f"{B}.box.size.y": b.width, f"{B}.box.size.z": b.height,
                                      f"{B}.box.heading": b.heading, f"{B}.type": int(lb.type),
                                      f"{B}.num_lidar_points_in_box": int(lb.num_lidar_points_in_box),
                                      f"{B}.num_top_lidar_points_in_box": int(lb.num_top_lidar_points_in_box),
                                      f"{B}.speed.x": m.speed_x, f"{B}.speed.y": m.speed_y, f"{B}.speed.z": m.speed_z})
        if context is None:
            context = ctx
            for c in f.context.camera_calibrations:
                C = "[CameraCalibrationComponent]"
                intr = dict(zip(["f_u", "f_v", "c_u", "c_v", "k1", "k2", "p1", "p2", "k3"], c.intrinsic))
                rows["camera_calibration"].append({"key.segment_context_name": ctx, "key.camera_name": int(c.name),
                                                   **{f"{C}.intrinsic.{k}": v for k, v in intr.items()},
                                                   f"{C}.extrinsic.transform": list(c.extrinsic.transform), f"{C}.width": c.width,
                                                   f"{C}.height": c.height, f"{C}.rolling_shutter_direction": c.rolling_shutter_direction})
            for c in f.context.laser_calibrations:
                L = "[LiDARCalibrationComponent]"
                rows["lidar_calibration"].append({"key.segment_context_name": ctx, "key.laser_name": int(c.name),
                                                  f"{L}.extrinsic.transform": list(c.extrinsic.transform),
                                                  f"{L}.beam_inclination.min": c.beam_inclination_min,
                                                  f"{L}.beam_inclination.max": c.beam_inclination_max,
                                                  f"{L}.beam_inclination.values": list(c.beam_inclinations) or None})
    types = {".values": pa.list_(pa.float32()), ".shape": pa.list_(pa.int32(), 3), ".transform": pa.list_(pa.float64(), 16)}
    for component, items in rows.items():
        if not items:
            continue
        folder = Path(root) / split / component
        folder.mkdir(parents=True, exist_ok=True)
        arrays = {}
        for name in items[0]:
            values = [it[name] for it in items]
            kind = next((t for suffix, t in types.items() if name.endswith(suffix)), None)
            if name.endswith("beam_inclination.values"):
                kind = pa.list_(pa.float64())
            arrays[name] = pa.array(values, type=kind)
        pq.write_table(pa.table(arrays), folder / f"{context}.parquet")
    return context
