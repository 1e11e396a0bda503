"""Instance poses against the annotated box they follow: the box's pose per step, and the mean
errors after the constant canonical-to-box offset that fits best (the canonical frame is arbitrary)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from idsplat_ns.data.tracks import box_corners
from idsplat_ns.eval.instance_pose_errors import match_instance
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks


def matching_box_poses(inst: InstanceTrack, train_scene, tracks: InstanceTracks) -> tuple[list, np.ndarray] | None:
    """Per step the pose [4, 4] (or None) of the annotated box that holds most of the instance's
    points at its canonical frame (``match_instance``), and the box's size [3]; None if no box does."""
    index = match_instance(train_scene, inst)
    if index is None:
        return None
    box = train_scene.tracks[index]
    return [box.pose_at_frame(int(f)) for f in tracks.frame_indices], np.asarray(box.size, np.float64)


def pose_errors(poses: dict, boxes: list, size: np.ndarray) -> tuple[float, ...]:  # poses: step -> [4, 4]
    """Mean 3D [m], height [m], tilt [deg], yaw [deg] and box-corner [m] error after the best
    constant offset (the corners weigh position and rotation as a render of the vehicle does)."""
    offsets = [np.linalg.inv(P) @ boxes[k] for k, P in poses.items()]
    C = np.eye(4)
    C[:3, 3] = np.mean([o[:3, 3] for o in offsets], axis=0)
    C[:3, :3] = Rotation.from_matrix(np.stack([o[:3, :3] for o in offsets])).mean().as_matrix()
    e3, ez, et, ey, ec = [], [], [], [], []
    for k, P in poses.items():
        X, B = P @ C, boxes[k]
        local = B[:3, :3].T @ (X[:3, 3] - B[:3, 3])
        rotvec = Rotation.from_matrix(B[:3, :3].T @ X[:3, :3]).as_rotvec()
        tilt = rotvec[:2]
        e3.append(np.linalg.norm(local))
        ez.append(abs(local[2]))
        et.append(np.degrees(np.linalg.norm(tilt)))
        ey.append(np.degrees(abs(rotvec[2])))
        ec.append(np.linalg.norm(box_corners(X, size) - box_corners(B, size), axis=1).mean())
    return float(np.mean(e3)), float(np.mean(ez)), float(np.mean(et)), float(np.mean(ey)), float(np.mean(ec))
