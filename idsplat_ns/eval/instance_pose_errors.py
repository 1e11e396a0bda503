"""Recovered instance poses against ground-truth tracks (tests, benchmarks; never the pipeline).

An instance is matched to the ground-truth box that contains most of its points at its canonical
frame. Its canonical frame is arbitrary (axis-aligned, at the box centre of one frame), so poses
are compared after transporting the box through the estimated motion: the predicted box pose at
time t is ``T_t T_c^-1 B_c`` (T: estimated canonical-to-world, B: ground-truth box-to-world, c: the
canonical frame). The error is zero exactly when the estimated motion equals the true motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from idsplat_ns.data.geometry import invert_pose, transform_points
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import points_in_box
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks


@dataclass
class InstancePoseErrors:
    """Per-frame errors of one matched instance."""

    instance_id: int
    track_index: int
    """Index of the matched ground-truth track in ``scene.tracks``."""
    frames: np.ndarray
    """[K] frames (excluding the canonical one) with a valid estimate and a ground-truth pose."""
    translation: np.ndarray
    """[K] metres."""
    rotation_deg: np.ndarray
    """[K] degrees."""
    point_counts: np.ndarray
    """[K] lidar points of the instance at those frames."""
    max_points: int
    """Most lidar points the instance had at one frame."""


def match_instance(scene: Scene, inst: InstanceTrack, min_fraction: float = 0.5) -> Optional[int]:
    """Index of the ground-truth track whose box holds most of the instance's points at its
    canonical frame (at least ``min_fraction`` of them), or None."""
    frame_index = int(scene.frame_indices[inst.canonical_frame])
    pts = transform_points(inst.poses[inst.canonical_frame], inst.canonical_points)
    best, best_n = None, 0
    for ti, track in enumerate(scene.tracks):
        pose = track.pose_at_frame(frame_index)
        if pose is None:
            continue
        n = int(points_in_box(pts, pose, track.size, margin=0.2).sum())
        if n > best_n:
            best, best_n = ti, n
    return best if best_n >= min_fraction * len(pts) else None


def instance_pose_errors(scene: Scene, inst: InstanceTrack, track_index: int) -> InstancePoseErrors:
    """Translation and rotation errors at every valid non-canonical frame of a matched instance."""
    track = scene.tracks[track_index]
    c = inst.canonical_frame
    B_c = track.pose_at_frame(int(scene.frame_indices[c]))
    frames, t_err, r_err = [], [], []
    for k in np.nonzero(inst.valid)[0]:
        B_t = track.pose_at_frame(int(scene.frame_indices[k]))
        if k == c or B_t is None:
            continue
        pred = inst.poses[k] @ invert_pose(inst.poses[c]) @ B_c
        frames.append(k)
        t_err.append(np.linalg.norm(pred[:3, 3] - B_t[:3, 3]))
        cos = (np.trace(pred[:3, :3] @ B_t[:3, :3].T) - 1) / 2
        r_err.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    frames = np.array(frames, int)
    return InstancePoseErrors(inst.instance_id, track_index, frames, np.array(t_err), np.array(r_err),
                              inst.point_counts[frames], int(inst.point_counts.max(initial=0)))


@dataclass
class TrackingSummary:
    """Errors over all instances matched to moving vehicles."""

    per_instance: list[InstancePoseErrors]
    median_translation: float
    """Median over the frames where a matched instance has at least ``min_points`` points (metres;
    nan if none)."""
    median_rotation_deg: float
    """Same, rotation in degrees."""
    median_translation_instances: float
    """Median over all frames of the instances that have at least ``min_points`` points at some frame."""
    median_rotation_deg_instances: float
    """Same, rotation in degrees."""
    matched_tracks: int
    """Moving-vehicle tracks matched by some instance."""
    moving_vehicle_tracks: int
    """Moving-vehicle ground-truth tracks in the scene."""
    frames_evaluated: int
    """Frames that entered the medians."""


def summarise_errors(scene: Scene, tracks: InstanceTracks, min_points: int = 50, groups: tuple[str, ...] = ("vehicle",)) -> TrackingSummary:
    """Match every instance (dynamic and static) to ground truth and summarise the moving ones."""
    per = []
    for inst in tracks.instances + tracks.static_instances:
        ti = match_instance(scene, inst)
        if ti is None or not scene.tracks[ti].moving or scene.tracks[ti].group not in groups:
            continue
        per.append(instance_pose_errors(scene, inst, ti))
    def med(x):
        return float(np.median(x)) if len(x) else float("nan")

    empty = np.zeros(0)
    t = np.concatenate([e.translation[e.point_counts >= min_points] for e in per] or [empty])
    r = np.concatenate([e.rotation_deg[e.point_counts >= min_points] for e in per] or [empty])
    big = [e for e in per if e.max_points >= min_points]
    t_i = np.concatenate([e.translation for e in big] or [empty])
    r_i = np.concatenate([e.rotation_deg for e in big] or [empty])
    moving = sum(1 for tr in scene.tracks if tr.moving and tr.group in groups)
    return TrackingSummary(per, med(t), med(r), med(t_i), med(r_i), len({e.track_index for e in per}), moving, len(t))
