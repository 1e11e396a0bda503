"""Convert the readers' :class:`FrameRecord` stream to the project's :class:`Scene` (one converter
for v1 and v2, so both layouts give the same scene).

Conventions applied here, once: recentring on the first kept frame's vehicle pose (translation
only), seconds since the first kept frame's timestamp (raw microseconds kept), OpenCV camera axes,
lidar as world rays with per-pixel origin and time for TOP, intensity ``tanh(raw)`` in [0, 1),
and each frame's ego pose (and sweep pose) at the frame's time: ``Frame.pose`` is the vehicle about
mid-sweep, ``timestamp_micros`` the sweep's start, so the frame poses are stamped with their own
time (:func:`~idsplat_ns.data.waymo.range_image.pose_sweep_fraction`) and interpolated to the frame
times. The 3D labels stay in the frame pose's coordinates, as Waymo defines them.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Iterable, Optional

import numpy as np

from idsplat_ns.data.camera import CameraImage
from idsplat_ns.data.geometry import interpolate_poses
from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.scene import Scene, recentring_transform
from idsplat_ns.data.waymo.calibration import camera_intrinsics, camera_to_world, rolling_shutter
from idsplat_ns.data.waymo.labels import build_tracks
from idsplat_ns.data.waymo.range_image import (
    SWEEP_SECONDS,
    column_fire_fractions,
    pose_sweep_fraction,
    range_image_rays,
    row_inclinations,
)
from idsplat_ns.data.waymo.records import LASER_NAMES, FrameRecord, LidarFrame, SegmentCalibration
from idsplat_ns.errors import IDSplatError

_LASER_IDS = {name: number for number, name in LASER_NAMES.items()}


def _resize_jpeg(data: bytes, width: int, height: int, where: str) -> np.ndarray:
    """Decode a JPEG and area-resample it to width x height: [H, W, 3] uint8."""
    from PIL import Image

    try:
        img = Image.open(io.BytesIO(data))
        img.draft("RGB", (width, height))  # let the JPEG decoder do the power-of-two part cheaply
        img = img.convert("RGB")
    except Exception as err:  # PIL raises several types for a corrupt stream
        raise IDSplatError(f"{where}: the JPEG image does not decode ({err}); the segment file is damaged") from None
    if img.size != (width, height):
        img = img.resize((width, height), Image.Resampling.BOX)
    return np.asarray(img)


def lidar_rays(
    lidar: LidarFrame,
    calib: SegmentCalibration,
    frame_pose_world: np.ndarray,  # [4, 4] vehicle to recentred world
    world_from_raw: np.ndarray,  # [4, 4]
    frame_time: float,
) -> dict[str, np.ndarray]:
    """All rays of one lidar in one frame: first-return pixels all kept (no-return flagged), second
    returns only where they hit."""
    lc = calib.lidars[lidar.name]
    H, W = lidar.return1.shape[:2]
    incl = row_inclinations(H, lc.beam_inclinations, lc.inclination_min, lc.inclination_max)
    pixel_pose = None
    if lidar.pixel_pose is not None:
        # Per-pixel vehicle-to-raw-world; recentre its translation like everything else.
        pixel_pose = np.asarray(lidar.pixel_pose, dtype=np.float64).copy()
        pixel_pose[..., 3:6] += world_from_raw[:3, 3]
    origins, directions, ranges, returned = range_image_rays(
        lidar.return1[..., 0], lc.extrinsic, incl, frame_pose_world, pixel_pose
    )
    intensity = np.where(returned, np.tanh(np.maximum(lidar.return1[..., 1].reshape(-1), 0.0)), 0.0).astype(np.float32)
    if pixel_pose is not None:
        fractions = column_fire_fractions(pixel_pose, W)
        times = frame_time + np.broadcast_to(fractions[None, :], (H, W)).reshape(-1) * SWEEP_SECONDS
    else:  # no per-pixel pose: the frame pose is about mid-sweep
        times = np.full(H * W, frame_time + SWEEP_SECONDS / 2)
    beams = np.repeat(np.arange(H, dtype=np.int16), W)
    out = {
        "origins": origins, "directions": directions, "ranges": ranges, "intensities": intensity,
        "times": times, "returned": returned, "beam_ids": beams, "return_index": np.ones(H * W, np.int8),
    }
    if lidar.return2 is not None:
        r2 = lidar.return2[..., 0].reshape(-1)
        hit = r2 > 0
        out["origins"] = np.concatenate([origins, origins[hit]])
        out["directions"] = np.concatenate([directions, directions[hit]])
        out["ranges"] = np.concatenate([ranges, r2[hit].astype(np.float64)])
        i2 = np.tanh(np.maximum(lidar.return2[..., 1].reshape(-1)[hit], 0.0)).astype(np.float32)
        out["intensities"] = np.concatenate([intensity, i2])
        out["times"] = np.concatenate([times, times[hit]])
        out["returned"] = np.concatenate([returned, np.ones(int(hit.sum()), bool)])
        out["beam_ids"] = np.concatenate([beams, beams[hit]])
        out["return_index"] = np.concatenate([out["return_index"], np.full(int(hit.sum()), 2, np.int8)])
    out["sensor_ids"] = np.full(len(out["ranges"]), _LASER_IDS.get(lidar.name, 0), np.int16)
    return out


def assemble_scene(
    calib: SegmentCalibration,
    frames: Iterable[FrameRecord],
    source_path: Optional[Path],
    image_scale: float = 1.0,
    metadata: Optional[dict] = None,
) -> Scene:
    """Build the Scene from the kept frames (consumed one at a time)."""
    images: list[CameraImage] = []
    sweeps: list[LidarSweep] = []
    frame_indices, frame_times, frame_poses, pose_times, raw_times = [], [], [], [], []
    label_frames = []
    world_from_raw = None
    t0 = None
    where = str(source_path) if source_path is not None else calib.context_name
    for rec in frames:
        if world_from_raw is None:
            world_from_raw = recentring_transform(rec.pose)
            t0 = float(rec.timestamp_micros)
        frame_time = (float(rec.timestamp_micros) - t0) * 1e-6
        pose_world = world_from_raw @ rec.pose
        frame_indices.append(rec.index)
        frame_times.append(frame_time)
        raw_times.append(rec.timestamp_micros)
        frame_poses.append(pose_world)
        # The frame pose is the vehicle about mid-sweep, not at the sweep's start (timestamp_micros).
        top_pose = next((lid.pixel_pose for lid in rec.lidars if lid.name == "TOP"), None)
        pose_times.append(frame_time + pose_sweep_fraction(top_pose, rec.pose[:3, 3]) * SWEEP_SECONDS)
        for cam in rec.cameras:
            cc = calib.cameras[cam.name]
            intr = camera_intrinsics(cc)
            image_array, image_bytes = None, cam.image
            if image_scale != 1.0:
                intr = intr.scaled(image_scale)
                image_array = _resize_jpeg(cam.image, intr.width, intr.height, f"{where}: frame {rec.index} {cam.name}")
                image_bytes = None
            meta = {
                "shutter": cam.shutter,
                "trigger_time": cam.trigger_time,
                "readout_done_time": cam.readout_done_time,
                "image_scale": image_scale,
            }
            if cam.panoptic_label is not None:
                meta["panoptic_label_png"] = cam.panoptic_label
                meta["panoptic_label_divisor"] = cam.panoptic_label_divisor
            if cam.name in rec.projected_labels:
                meta["projected_lidar_labels"] = {lid: box for lid, box in rec.projected_labels[cam.name]}
            images.append(
                CameraImage(
                    camera=cam.name,
                    frame_index=rec.index,
                    time=cam.pose_timestamp - t0 * 1e-6,
                    raw_timestamp=cam.pose_timestamp * 1e6,
                    camera_to_world=camera_to_world(cc, cam.pose, world_from_raw),
                    intrinsics=intr,
                    image=image_array,
                    image_bytes=image_bytes,
                    rolling_shutter=rolling_shutter(cc, cam),
                    metadata=meta,
                )
            )
        parts = [lidar_rays(lid, calib, pose_world, world_from_raw, frame_time) for lid in rec.lidars]
        if parts:
            cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        else:
            cat = {
                "origins": np.zeros((0, 3)), "directions": np.zeros((0, 3)), "ranges": np.zeros(0),
                "intensities": np.zeros(0, np.float32), "times": np.zeros(0), "returned": np.zeros(0, bool),
                "beam_ids": np.zeros(0, np.int16), "return_index": np.zeros(0, np.int8), "sensor_ids": np.zeros(0, np.int16),
            }
        sweeps.append(
            LidarSweep(
                frame_index=rec.index,
                time=frame_time,
                raw_timestamp=float(rec.timestamp_micros),
                sensor_to_world=pose_world,  # the vehicle at the sweep's time: set below
                origins=cat["origins"],
                directions=cat["directions"],
                ranges=cat["ranges"],
                intensities=cat["intensities"],
                times=cat["times"],
                returned=cat["returned"],
                sensor_ids=cat["sensor_ids"],
                beam_ids=cat["beam_ids"],
                metadata={"return_index": cat["return_index"], "lidars": [lid.name for lid in rec.lidars]},
            )
        )
        label_frames.append((rec.index, frame_time, pose_world, rec.labels))
    if world_from_raw is None:
        raise IDSplatError(f"{where}: no frames in the selected range; check the start/end frame options")
    # Each frame's ego pose at the frame's time (the sweep start), from the frame poses at their own
    # times (interpolated; extrapolated at the ends with the end segments' velocity).
    ego_poses = interpolate_poses(np.array(pose_times), np.stack(frame_poses), np.array(frame_times), extrapolate=True)
    top = calib.lidars.get("TOP")
    for sweep, ego in zip(sweeps, ego_poses):
        sweep.sensor_to_world = ego @ top.extrinsic if top is not None else ego
    meta = {"context_name": calib.context_name, "stats": calib.stats, "image_scale": image_scale,
            "raw_frame_timestamps_micros": np.array(raw_times, dtype=np.int64),
            "frame_pose_times": np.array(pose_times, dtype=np.float64)}
    meta.update(metadata or {})
    return Scene(
        name=calib.context_name,
        source="waymo",
        root=source_path,
        frame_indices=np.array(frame_indices, dtype=int),
        frame_times=np.array(frame_times, dtype=np.float64),
        ego_poses=ego_poses,
        images=images,
        lidar=sweeps,
        tracks=build_tracks(label_frames),
        world_from_raw=world_from_raw,
        time_origin_raw=t0,
        raw_time_unit_seconds=1e-6,
        metadata=meta,
    )
