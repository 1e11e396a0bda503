"""Per-instance trajectories from lidar registration (paper Sec. 3.3).

The canonical frame of an instance is the centre of the axis-aligned box of its points at the frame
with the most points, with identity rotation. The other frames, in decreasing order of point count,
are registered against the growing canonical point set; a success gives that frame's pose and adds
its points (mapped back to the canonical frame) to the set. The ``centroid`` method is the paper's
ablation (c): translation only, from the points' centroids.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Optional

import numpy as np
from tqdm import tqdm

from idsplat_ns.data.geometry import invert_pose, transform_points
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.heading_flips import HeadingFlipConfig, canonical_box_centre, detect_flips, flip_about
from idsplat_ns.instances.lifting import InstanceObservation, LiftedInstances
from idsplat_ns.instances.registration import RegistrationConfig, icp_point_to_plane, register, registration_fitness
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks, fill_invalid_poses


@dataclass(frozen=True)
class TrajectoryConfig:
    """How instance poses are estimated from their lidar points."""

    method: Literal["registration", "centroid"] = "registration"
    """``registration`` (the paper) or ``centroid`` (ablation c: translation from point centroids)."""
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    """RANSAC settings."""
    min_points: int = 10
    """Instances never seen with at least this many points are dropped."""
    heading_flips: HeadingFlipConfig = field(default_factory=HeadingFlipConfig)
    """Front/back flips of registrations, found from the direction of travel and turned back
    (ours; see instances/heading_flips.py)."""


def _obs_features(features: PointFeatures, iid: int, obs: InstanceObservation) -> np.ndarray:
    f = features.features.get((iid, obs.frame))
    if f is None:  # every lifted observation is described by the extractors; anything else is a bug
        raise ValueError(f"{features.extractor} gave no features for instance {iid} at frame {obs.frame}")
    return f


def estimate_instance_track(
    iid: int,
    label: str,
    observations: list[InstanceObservation],
    features: Optional[PointFeatures],
    num_frames: int,
    config: TrajectoryConfig,
    times: Optional[np.ndarray] = None,  # [F] seconds; needed for heading-flip correction
) -> InstanceTrack:
    """Poses of one instance at every frame where registration succeeds."""
    counts = np.zeros(num_frames, np.int64)
    for o in observations:
        counts[o.frame] = len(o.points)
    order = sorted(observations, key=lambda o: (-len(o.points), o.frame))
    ref = order[0]
    centre = 0.5 * (ref.points.min(0) + ref.points.max(0))
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    valid = np.zeros(num_frames, bool)
    fitness = np.zeros(num_frames)
    poses[ref.frame, :3, 3] = centre
    valid[ref.frame], fitness[ref.frame] = True, 1.0

    def colours_of(o: InstanceObservation) -> Optional[np.ndarray]:
        return None if features is None or not features.colors else features.colors.get((iid, o.frame))

    canon_pts = [ref.points - centre]
    canon_cols = [colours_of(ref)]
    canon_frames = [ref.frame]
    if config.method == "centroid":
        ref_centroid = ref.points.mean(0)
        for o in order[1:]:
            shift = o.points.mean(0) - ref_centroid
            poses[o.frame, :3, 3] = centre + shift
            valid[o.frame], fitness[o.frame] = True, 1.0
            canon_pts.append(o.points - centre - shift)
            canon_cols.append(colours_of(o))
    else:
        if features is None:
            raise ValueError("registration needs point features (pass the extractor's output, or use method='centroid')")
        canon_feat = [_obs_features(features, iid, ref)]
        for o in order[1:]:
            result = register(np.concatenate(canon_pts), np.concatenate(canon_feat), o.points,
                              _obs_features(features, iid, o), config.registration)
            fitness[o.frame] = result.fitness
            if not result.success:
                continue
            poses[o.frame], valid[o.frame] = result.transform, True
            canon_pts.append(transform_points(invert_pose(result.transform), o.points))
            canon_feat.append(_obs_features(features, iid, o))
            canon_cols.append(colours_of(o))
            canon_frames.append(o.frame)
        if config.heading_flips.enabled and times is not None:
            by_frame = {o.frame: o for o in observations}
            _correct_flips(poses, valid, fitness, counts, canon_pts, canon_frames, by_frame, times, config)
    colors = None if any(c is None for c in canon_cols) else np.concatenate(canon_cols)
    if config.method == "centroid":
        canon_frames = [ref.frame] + [o.frame for o in order[1:]]
    point_frames = np.concatenate([np.full(len(p), f, np.int32) for p, f in zip(canon_pts, canon_frames)])
    return InstanceTrack(
        instance_id=iid, label=label, canonical_points=np.concatenate(canon_pts), canonical_colors=colors,
        poses=fill_invalid_poses(poses, valid), valid=valid, point_counts=counts, fitness=fitness,
        canonical_frame=int(ref.frame), point_frames=point_frames,
    )


def _correct_flips(
    poses: np.ndarray,  # [F, 4, 4] (updated in place)
    valid: np.ndarray,  # [F] bool
    fitness: np.ndarray,  # [F] (updated in place)
    counts: np.ndarray,  # [F] lidar points per frame
    canon_pts: list[np.ndarray],  # canonical chunks, one per registered frame (updated in place)
    canon_frames: list[int],  # the frame of each chunk
    by_frame: dict[int, InstanceObservation],
    times: np.ndarray,  # [F] seconds
    config: TrajectoryConfig,
) -> None:
    """Turn back front/back-flipped registrations (see heading_flips.py): half a turn about the box
    centre of the unflipped canonical points, refined by ICP on them, and re-map those frames'
    canonical points."""
    flips = config.heading_flips
    t = poses[valid, :3, 3]
    if len(t) < 2 or np.max(np.linalg.norm(t[:, None] - t[None], axis=-1)) < flips.min_track_displacement:
        return
    flipped = detect_flips(times, poses, valid, counts, flips)
    if not flipped.any():
        return
    keep = [k for k, f in enumerate(canon_frames) if not flipped[f]]
    reference = np.concatenate([canon_pts[k] for k in keep])
    centre = canonical_box_centre(reference)
    reg = config.registration
    for k, f in enumerate(canon_frames):
        if not flipped[f]:
            continue
        target = by_frame[f].points
        turned = flip_about(poses[f], centre)
        refined = icp_point_to_plane(turned, reference, target, reg.icp_iterations, reg.icp_distance)
        poses[f] = refined
        fitness[f] = registration_fitness(refined, reference, target, reg.inlier_distance)
        canon_pts[k] = transform_points(invert_pose(refined), target)


def estimate_trajectories(
    scene: Scene,
    lifted: LiftedInstances,
    features: Optional[PointFeatures],
    config: TrajectoryConfig = TrajectoryConfig(),
    progress: bool = True,
) -> InstanceTracks:
    """Trajectories of every lifted instance (before static conversion and smoothing)."""
    tracks = []
    items = sorted(lifted.observations.items())
    for iid, obs in tqdm(items, desc="registration", disable=not progress):
        if not obs or max(len(o.points) for o in obs) < config.min_points:
            continue
        tracks.append(estimate_instance_track(iid, lifted.labels[iid], obs, features, scene.num_frames, config,
                                              np.asarray(scene.frame_times, np.float64)))
    meta = {"trajectory_method": config.method, "features": None if features is None else features.extractor}
    return InstanceTracks(np.asarray(scene.frame_indices), np.asarray(scene.frame_times, np.float64), tracks, [], meta)
