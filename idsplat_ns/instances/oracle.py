"""ORACLE MODE ONLY: instance tracks built from the dataset's ground-truth boxes.

This is the SplatAD-style upper bound ("oracle tracks"): it reads ``Scene.tracks`` (annotations),
which the self-supervised path never does (see ../shared/DESIGN.md). Use it only for the
explicitly named oracle mode and for comparisons against it.

Per ground-truth track: the canonical frame is the box frame (x forward, y left, z up, origin at
the box centre), the poses are the annotated box-to-world poses on the scene's frame grid (valid
where annotated), and the canonical points are the lidar points inside the box at each frame,
moved into the box frame with the box pose at each point's own time (lidar rays span a sweep,
and a moving box travels during it), concatenated over the frames and subsampled.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from idsplat_ns.data.geometry import interpolate_poses
from idsplat_ns.data.scene import Scene
from idsplat_ns.data.tracks import ObjectTrack
from idsplat_ns.instances.tracks import (
    InstanceTrack,
    InstanceTracks,
    fill_invalid_poses,
)


def _box_points(
    track: ObjectTrack, scene: Scene, frames: set[int] | None, box_margin: float, ground_clearance: float
) -> tuple[list[np.ndarray], dict[int, int]]:
    """Box-frame points of ``track`` per used frame, and the point count per dataset frame index."""
    size = np.asarray(track.size, dtype=np.float64)
    half = size / 2 + box_margin
    chunks: list[np.ndarray] = []
    counts: dict[int, int] = {}
    # A generous world-space pre-filter radius: the box's half diagonal plus how far it moves in a sweep.
    speed = 0.0
    if len(track.times) > 1:
        speed = float(np.max(np.linalg.norm(np.diff(track.poses[:, :3, 3], axis=0), axis=1)
                             / np.maximum(np.diff(track.times), 1e-6)))
    for sweep in scene.lidar:
        if frames is not None and sweep.frame_index not in frames:
            continue
        k = track.index_of_frame(sweep.frame_index)
        if k is None:
            continue
        points = sweep.points
        times = sweep.times[sweep.returned]
        if len(points) == 0:
            continue
        sweep_span = float(np.ptp(times)) if len(times) else 0.0
        radius = float(np.linalg.norm(half)) + speed * sweep_span + 0.5
        near = np.flatnonzero(np.linalg.norm(points - track.poses[k, :3, 3], axis=1) <= radius)
        if len(near) == 0:
            counts[sweep.frame_index] = 0
            continue
        # Box pose at each ray's time (within the annotated span; extrapolated by at most a sweep).
        T = interpolate_poses(track.times, track.poses, times[near], extrapolate=True)
        local = np.einsum("nji,nj->ni", T[:, :3, :3], points[near] - T[:, :3, 3])
        inside = np.all(np.abs(local) <= half, axis=1) & (local[:, 2] >= -size[2] / 2 + ground_clearance)
        chunks.append(local[inside])
        counts[sweep.frame_index] = int(inside.sum())
    return chunks, counts


def oracle_instance_tracks(
    scene: Scene,
    frames: Iterable[int] | None = None,
    moving_only: bool = True,
    min_points: int = 10,
    max_points_per_instance: int = 50_000,
    box_margin: float = 0.05,
    ground_clearance: float = 0.05,
    seed: int = 0,
) -> InstanceTracks:
    """ORACLE MODE: :class:`InstanceTracks` from the scene's ground-truth tracks.

    ``frames``: dataset frame indices whose lidar may give canonical points (the training split;
    None: all). Poses cover every scene frame where the track is annotated (the oracle knows the
    boxes at held-out frames too, as in SplatAD). ``moving_only`` keeps tracks flagged as moving;
    tracks with fewer than ``min_points`` box points in total are dropped (the paper's >= 10 lidar
    point filter). ``box_margin`` (metres) grows the box for point collection (surface points on
    the box faces); points less than ``ground_clearance`` above the box bottom are left out (the
    road under and around the object, which annotated boxes touch). Instance IDs are 1.. in track order; ``metadata['track_ids']`` maps each
    ID (as a string) to the dataset's track ID.
    """
    frame_set = None if frames is None else {int(f) for f in frames}
    F = scene.num_frames
    row_of_frame = {int(f): k for k, f in enumerate(scene.frame_indices)}
    rng = np.random.default_rng(seed)
    instances: list[InstanceTrack] = []
    track_ids: dict[str, str] = {}
    for track in scene.tracks:
        if moving_only and not track.moving:
            continue
        chunks, counts = _box_points(track, scene, frame_set, box_margin, ground_clearance)
        points = np.concatenate(chunks) if chunks else np.zeros((0, 3))
        if len(points) < max(min_points, 1):
            continue
        if len(points) > max_points_per_instance:
            points = points[np.sort(rng.choice(len(points), max_points_per_instance, replace=False))]
        poses = np.tile(np.eye(4), (F, 1, 1))
        valid = np.zeros(F, bool)
        for k_track, f in enumerate(track.frame_indices):
            row = row_of_frame.get(int(f))
            if row is not None:
                poses[row] = track.poses[k_track]
                valid[row] = True
        if not valid.any():
            continue
        point_counts = np.array([counts.get(int(f), 0) for f in scene.frame_indices], dtype=np.int64)
        instance_id = len(instances) + 1
        track_ids[str(instance_id)] = track.track_id
        instances.append(
            InstanceTrack(
                instance_id=instance_id,
                label=track.label,
                canonical_points=points,
                canonical_colors=None,
                poses=fill_invalid_poses(poses, valid),
                valid=valid,
                point_counts=point_counts,
                fitness=valid.astype(np.float64),  # annotations: exact by definition
                canonical_frame=int(np.argmax(np.where(valid, point_counts, -1))),
            )
        )
    metadata = {"source": "oracle_ground_truth_boxes", "moving_only": moving_only, "min_points": min_points,
                "track_ids": track_ids}
    return InstanceTracks(
        frame_indices=np.asarray(scene.frame_indices).copy(),
        frame_times=np.asarray(scene.frame_times, dtype=np.float64).copy(),
        instances=instances,
        static_instances=[],
        metadata=metadata,
    )
