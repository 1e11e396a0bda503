"""Validation of Waymo records (v1 and v2 alike), applied by each reader where it knows the file.

The readers produce :class:`SegmentCalibration` and :class:`FrameRecord`; these functions run the
format-free checks of :mod:`idsplat_ns.data.validation` on them, so a NaN pose, a zero focal length
or a non-increasing timestamp stops the load in one line naming the file, the frame and the field.
Poses whose rotation is slightly off are renormalised in place (with one warning).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from idsplat_ns.data.validation import MAX_LIDAR_RANGE_M, check_finite, check_intrinsics, check_pose, check_within
from idsplat_ns.data.waymo.records import FrameRecord, SegmentCalibration
from idsplat_ns.errors import IDSplatError


MAX_BOX_SIZE_M = 50.0
"""A labelled box larger than this along any axis is damaged (the longest road vehicles are ~25 m)."""
MAX_SPEED_MPS = 150.0
"""A labelled speed above this (540 km/h) is damaged."""


def check_calibration(calib: SegmentCalibration, camera_file: str, lidar_file: str) -> None:
    """Intrinsics positive with the principal point inside the image; extrinsics rigid."""
    for name, c in calib.cameras.items():
        intr = check_finite(c.intrinsic, camera_file, f"camera {name} intrinsic")
        if intr.size < 9:
            raise IDSplatError(f"{camera_file}: camera {name} intrinsic has {intr.size} values, expected 9 (f_u, f_v, c_u, c_v, k1..k3)")
        check_intrinsics(intr[0], intr[1], intr[2], intr[3], c.width, c.height, camera_file, None)
        c.extrinsic = check_pose(c.extrinsic, camera_file, f"camera {name} extrinsic")
    for name, lc in calib.lidars.items():
        lc.extrinsic = check_pose(lc.extrinsic, lidar_file, f"lidar {name} extrinsic")
        if lc.beam_inclinations is not None:
            check_finite(lc.beam_inclinations, lidar_file, f"lidar {name} beam inclinations")
        check_finite(np.array([lc.inclination_min, lc.inclination_max]), lidar_file, f"lidar {name} inclination range")


def check_frame(
    rec: FrameRecord,
    previous_micros: Optional[int],
    pose_file: str,
    camera_file: str,
    lidar_file: str,
    label_file: Optional[str] = None,
) -> None:
    """One frame: vehicle and image poses rigid, times finite and after the previous frame's,
    range images and pixel poses finite, box labels finite with a plausible size and place.
    Fixes slightly-off rotations in place."""
    frame = rec.index
    if previous_micros is not None and rec.timestamp_micros <= previous_micros:
        kind = "duplicates" if rec.timestamp_micros == previous_micros else "is before"
        raise IDSplatError(
            f"{pose_file}: frame {frame}: timestamp {rec.timestamp_micros} {kind} the previous frame's "
            f"({previous_micros}); timestamps must increase"
        )
    rec.pose = check_pose(rec.pose, pose_file, "vehicle pose", frame)
    for cam in rec.cameras:
        cam.pose = check_pose(cam.pose, camera_file, f"{cam.name} image pose", frame)
        check_finite(np.array([cam.pose_timestamp]), camera_file, f"{cam.name} pose timestamp", frame)
    for lid in rec.lidars:
        # Ranges and intensities (channels 0, 1): a NaN range would become a NaN ray.
        check_finite(lid.return1[..., :2], lidar_file, f"lidar {lid.name} return 1", frame)
        if lid.return2 is not None:
            check_finite(lid.return2[..., :2], lidar_file, f"lidar {lid.name} return 2", frame)
        if lid.pixel_pose is not None:
            check_finite(lid.pixel_pose, lidar_file, f"lidar {lid.name} pixel pose", frame)
    for label in rec.labels:
        field = f"box {label.id}"
        check_within(label.center, -MAX_LIDAR_RANGE_M, MAX_LIDAR_RANGE_M, label_file or pose_file, f"{field} centre", frame, " m")
        # Boxes are at most a long articulated truck; a zero size is an empty box.
        check_within(label.size, 1e-3, MAX_BOX_SIZE_M, label_file or pose_file, f"{field} size", frame, " m")
        check_finite(np.array([label.heading]), label_file or pose_file, f"{field} heading", frame)
        check_within(label.speed, -MAX_SPEED_MPS, MAX_SPEED_MPS, label_file or pose_file, f"{field} speed", frame, " m/s")
