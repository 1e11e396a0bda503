"""Waymo Open Dataset v1: ``segment-*.tfrecord`` files with one ``Frame`` protobuf per record.

Frames are streamed: records before ``start`` are skipped by seeking, records from ``end`` on are
never read, and each kept frame is reduced to a :class:`FrameRecord` (JPEG bytes, decoded range
images of the chosen lidars, labels) before the next record is read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional, Sequence

import numpy as np

from idsplat_ns.data.waymo import proto
from idsplat_ns.data.waymo.checks import check_calibration, check_frame
from idsplat_ns.data.waymo.range_image import decode_compressed_matrix
from idsplat_ns.data.waymo.records import (
    CAMERA_NAMES,
    LASER_NAMES,
    BoxLabel,
    CameraCalib,
    CameraFrame,
    FrameRecord,
    LidarCalib,
    LidarFrame,
    SegmentCalibration,
)
from idsplat_ns.data.waymo.tfrecord import RecordRef, iter_records
from idsplat_ns.errors import IDSplatError


def _matrix(transform, what: str) -> np.ndarray:
    values = np.asarray(transform.transform, dtype=np.float64)
    if values.size != 16:
        raise IDSplatError(f"{what}: transform has {values.size} values, expected 16 (a 4x4 matrix)")
    return values.reshape(4, 4)


def parse_frame(data: bytes, path: Path, ref: RecordRef):
    """Parse one record as a Frame (one-line error naming file and offset if it is not one)."""
    frame = proto.Frame()
    try:
        frame.ParseFromString(data)
    except Exception as err:  # protobuf's DecodeError and friends
        raise IDSplatError(
            f"{path}: record {ref.index} at byte offset {ref.offset}: not a Waymo Frame protobuf ({type(err).__name__}); "
            "pass a Waymo v1 perception segment"
        ) from None
    if not frame.HasField("context") or not frame.context.name:
        raise IDSplatError(
            f"{path}: record {ref.index} at byte offset {ref.offset}: not a Waymo Frame (no context); "
            "pass a Waymo v1 perception segment"
        )
    return frame


def segment_calibration(frame, where: str) -> SegmentCalibration:
    """Calibrations from a frame's context."""
    cameras = {}
    for c in frame.context.camera_calibrations:
        name = CAMERA_NAMES.get(int(c.name), f"CAMERA_{int(c.name)}")
        cameras[name] = CameraCalib(
            name=name,
            intrinsic=np.asarray(c.intrinsic, dtype=np.float64),
            extrinsic=_matrix(c.extrinsic, f"{where}: camera {name} extrinsic"),
            width=int(c.width),
            height=int(c.height),
            rolling_shutter_direction=int(c.rolling_shutter_direction),
        )
    lidars = {}
    for c in frame.context.laser_calibrations:
        name = LASER_NAMES.get(int(c.name), f"LASER_{int(c.name)}")
        incl = np.asarray(c.beam_inclinations, dtype=np.float64)
        lidars[name] = LidarCalib(
            name=name,
            extrinsic=_matrix(c.extrinsic, f"{where}: lidar {name} extrinsic"),
            beam_inclinations=incl if incl.size else None,
            inclination_min=float(c.beam_inclination_min),
            inclination_max=float(c.beam_inclination_max),
        )
    stats = frame.context.stats
    return SegmentCalibration(
        context_name=frame.context.name,
        cameras=cameras,
        lidars=lidars,
        stats={"time_of_day": stats.time_of_day, "location": stats.location, "weather": stats.weather},
    )


def _box_label(label) -> BoxLabel:
    b, m = label.box, label.metadata
    return BoxLabel(
        id=label.id,
        type=int(label.type),
        center=np.array([b.center_x, b.center_y, b.center_z]),
        size=np.array([b.length, b.width, b.height]),
        heading=float(b.heading),
        speed=np.array([m.speed_x, m.speed_y, m.speed_z]),
        num_lidar_points=int(label.num_lidar_points_in_box),
        num_top_lidar_points=int(label.num_top_lidar_points_in_box),
    )


def frame_record(
    frame, index: int, cameras: Sequence[str], lidars: Sequence[str], where: str, second_return: bool = True
) -> FrameRecord:
    """Reduce a parsed Frame to the kept cameras, lidars and labels."""
    record = FrameRecord(index=index, timestamp_micros=int(frame.timestamp_micros), pose=_matrix(frame.pose, f"{where}: frame pose"))
    by_name = {CAMERA_NAMES.get(int(im.name), f"CAMERA_{int(im.name)}"): im for im in frame.images}
    for name in cameras:
        im = by_name.get(name)
        if im is None:
            raise IDSplatError(f"{where}: frame {index} has no {name} image (it has {sorted(by_name)}); choose cameras it has")
        seg = im.camera_segmentation_label
        record.cameras.append(
            CameraFrame(
                name=name,
                image=bytes(im.image),
                pose=_matrix(im.pose, f"{where}: {name} image pose"),
                pose_timestamp=float(im.pose_timestamp),
                shutter=float(im.shutter),
                trigger_time=float(im.camera_trigger_time),
                readout_done_time=float(im.camera_readout_done_time),
                panoptic_label=bytes(seg.panoptic_label) if seg.panoptic_label else None,
                panoptic_label_divisor=int(seg.panoptic_label_divisor),
            )
        )
    for laser in frame.lasers:
        name = LASER_NAMES.get(int(laser.name), f"LASER_{int(laser.name)}")
        if name not in lidars or not laser.ri_return1.range_image_compressed:
            continue  # a lidar with empty range images (e.g. Waymo's test frame) contributes no rays
        what = f"{where}: frame {index} lidar {name}"
        r1 = decode_compressed_matrix(laser.ri_return1.range_image_compressed, f"{what} return 1")
        r2 = None
        if second_return and laser.ri_return2.range_image_compressed:
            r2 = decode_compressed_matrix(laser.ri_return2.range_image_compressed, f"{what} return 2")
        pose = None
        if laser.ri_return1.range_image_pose_compressed:
            pose = decode_compressed_matrix(laser.ri_return1.range_image_pose_compressed, f"{what} pixel pose")
        record.lidars.append(LidarFrame(name=name, return1=r1, return2=r2, pixel_pose=pose))
    record.lidars.sort(key=lambda lf: sensor_rank(lf.name, LASER_NAMES))
    record.labels = [_box_label(label) for label in frame.laser_labels]
    for cam_labels in frame.projected_lidar_labels:
        cam = CAMERA_NAMES.get(int(cam_labels.name), f"CAMERA_{int(cam_labels.name)}")
        boxes = []
        for label in cam_labels.labels:
            b = label.box
            half = np.array([b.length, b.width]) / 2  # 2D boxes: length along u, width along v
            boxes.append((label.id, np.array([b.center_x - half[0], b.center_y - half[1], b.center_x + half[0], b.center_y + half[1]])))
        record.projected_labels[cam] = boxes
    return record


def read_v1(
    path: str | Path,
    cameras: Optional[Sequence[str]],
    lidars: Optional[Sequence[str]],
    start: int,
    end: Optional[int],
    second_return: bool = True,
) -> tuple[SegmentCalibration, Iterator[FrameRecord]]:
    """The segment's calibration (from frame ``start``) and a lazy iterator over its kept frames.

    ``cameras``/``lidars`` None means all that the segment has; unknown names raise before any
    frame is converted.
    """
    path = Path(path)
    records = iter_records(path, start=start, end=end)
    first = next(records, None)
    if first is None:
        raise IDSplatError(f"{path}: no frame at index {start} (the segment is shorter); lower the start frame")
    ref, data = first
    frame = parse_frame(data, path, ref)
    calib = segment_calibration(frame, str(path))
    check_calibration(calib, str(path), str(path))
    cam_names = resolve_names(cameras, list(calib.cameras), "camera", path)
    lidar_names = resolve_names(lidars, list(calib.lidars), "lidar", path)

    def checked(rec: FrameRecord, previous: Optional[int]) -> FrameRecord:
        check_frame(rec, previous, str(path), str(path), str(path))
        return rec

    def frames() -> Iterator[FrameRecord]:
        nonlocal frame
        rec = checked(frame_record(frame, ref.index, cam_names, lidar_names, str(path), second_return), None)
        previous = rec.timestamp_micros
        yield rec
        frame = None  # release the parsed first frame
        for r, d in records:
            rec = checked(frame_record(parse_frame(d, path, r), r.index, cam_names, lidar_names, str(path), second_return), previous)
            previous = rec.timestamp_micros
            yield rec

    return calib, frames()


def resolve_names(asked: Optional[Sequence[str]], available: list[str], kind: str, where) -> list[str]:
    """Upper-cased sensor names, checked against what the segment has (one-line error if not)."""
    if asked is None:
        table = CAMERA_NAMES if kind == "camera" else LASER_NAMES
        return sorted(available, key=lambda name: sensor_rank(name, table))
    names = [str(n).upper() for n in asked]
    missing = [n for n in names if n not in available]
    if missing:
        raise IDSplatError(f"{where}: no {kind} named {', '.join(missing)} in this segment (it has {', '.join(available)})")
    return names


def sensor_rank(name: str, table: dict[int, str]) -> int:
    """Waymo's enum number of a sensor name (unknown names last), for a stable sensor order."""
    for number, known in table.items():
        if known == name:
            return number
    return 1000
