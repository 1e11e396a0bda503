"""Waymo camera calibration in the project's conventions.

Waymo's camera frame is x forward, y left, z up; the project's is OpenCV (x right, y down,
z forward). The change of axes is applied once, here: ``camera_to_world = world_from_raw @
vehicle_to_world @ camera_to_vehicle @ WAYMO_FROM_OPENCV``. Intrinsics ``[f_u, f_v, c_u, c_v, k1,
k2, p1, p2, k3]`` follow OpenCV's definitions, and Waymo's pixel origin is the left/top edge of the
first pixel, as in :class:`Intrinsics`.
"""

from __future__ import annotations

import numpy as np

from idsplat_ns.data.camera import Intrinsics, RollingShutter
from idsplat_ns.data.waymo.records import SHUTTER_DIRECTIONS, CameraCalib, CameraFrame

WAYMO_FROM_OPENCV = np.array(
    [[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""[4, 4] maps OpenCV camera coordinates to Waymo camera coordinates (x_w = z_cv, y_w = -x_cv, z_w = -y_cv)."""


def camera_intrinsics(calib: CameraCalib) -> Intrinsics:
    """Intrinsics (with distortion k1, k2, p1, p2, k3) at the stored image resolution."""
    f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3 = (float(v) for v in calib.intrinsic[:9])
    return Intrinsics(
        fx=f_u, fy=f_v, cx=c_u, cy=c_v, width=int(calib.width), height=int(calib.height), distortion=(k1, k2, p1, p2, k3)
    )


def camera_to_world(
    calib: CameraCalib,
    vehicle_to_world_raw: np.ndarray,  # [4, 4] the image's own vehicle pose
    world_from_raw: np.ndarray,  # [4, 4] recentring
) -> np.ndarray:
    """[4, 4] OpenCV-axes camera pose in the recentred world."""
    return world_from_raw @ vehicle_to_world_raw @ calib.extrinsic @ WAYMO_FROM_OPENCV


def rolling_shutter(calib: CameraCalib, image: CameraFrame) -> RollingShutter:
    """Readout time from the first to the last row/column's mid-exposure, and its direction.

    Per Waymo's timing: the first line is exposed from the trigger for ``shutter`` seconds, the last
    line's exposure ends at readout-done, so mid-exposures span ``readout_done - trigger - shutter``.
    """
    readout = max(float(image.readout_done_time - image.trigger_time - image.shutter), 0.0)
    direction = SHUTTER_DIRECTIONS.get(int(calib.rolling_shutter_direction), "global")
    return RollingShutter(readout_seconds=readout if direction != "global" else 0.0, direction=direction)
