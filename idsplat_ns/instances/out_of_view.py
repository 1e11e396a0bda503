"""An instance carried through the frames where the lidar sees it and no camera does.

Registration places an instance only where its lidar points were painted from some image. A car
overtaking the ego comes up from behind, where no camera looks, and one passing the other way
leaves behind it; the lidar-motion source tracks both all the way round (its clusters,
:mod:`idsplat_ns.instances.lidar_motion`). Without poses there the instance ends at the last frame
a camera saw, while the held-out frame just after still shows its side filling the image, the
lidar losses find no one for its points, and those points seed static Gaussians along its path.

Out of the cameras' view there are no features, so each such frame, outwards from the track's
ends one at a time, takes the pose of the nearest posed frame moved by the shift of the lidar
view's centroid, refined by point-to-plane ICP onto its lidar points (as the chain's motion prior
does), and is accepted when the refined pose stays within the chain's gate of the prediction, is
upright, and explains at least the registration fitness threshold of the frame's points. What they are fitted
to is the lidar's whole view of the instance at the nearest posed frames, mapped by their poses,
not the canonical points: a car leaving shows its back, which no camera saw but the lidar did a
frame before. The first frame that fails ends the extension on that side. The lidar points of the
frames carried never join the instance's canonical points: no camera gave them a colour. Only
vehicles are carried: a walker's cluster changes shape from step to step.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Optional

import numpy as np

from idsplat_ns.data.geometry import invert_pose, transform_points
from idsplat_ns.instances.amodal_centre import sensors_in_canonical
from idsplat_ns.instances.motion_prior import motion_prior_pose
from idsplat_ns.instances.registration import RegistrationConfig, Visibility, registration_fitness, upright
from idsplat_ns.instances.tracks import InstanceTrack, fill_invalid_poses


def nearest_posed(valid: np.ndarray, times: np.ndarray, frame: int, count: int) -> list[int]:  # valid, times: [F]
    """The (up to) ``count`` posed frames nearest to ``frame`` in time, nearest first (ties: earlier)."""
    posed = np.flatnonzero(valid)
    order = np.lexsort((posed, np.abs(times[posed] - times[frame])))
    return [int(f) for f in posed[order[:count]]]


def extend_out_of_view(
    track: InstanceTrack,
    lidar_views: Mapping[int, np.ndarray],  # frame -> [N, 3] world: all the instance's lidar points there
    times: np.ndarray,  # [F] seconds
    registration: RegistrationConfig,
    max_frames: int,
    neighbours: int = 3,
    max_gap: float = 1.0,
    max_deviation: float = 1.0,
    sensors: Optional[np.ndarray] = None,  # [F, 3] world: where the lidar was at each frame
) -> InstanceTrack:
    """``track`` with up to ``max_frames`` frames of ``lidar_views`` posed past each end (see the
    module docstring); frames ``max_gap`` seconds or more from the last posed one are not reached.
    Vehicles only: a walker's or rider's cluster changes shape with every step, so a rigid fit
    to the frame before carries no pose."""
    if max_frames <= 0 or not lidar_views or track.num_valid == 0 or track.category != "vehicle":
        return track
    poses, valid = track.poses.copy(), track.valid.copy()
    fitness, counts = track.fitness.copy(), track.point_counts.copy()
    extended = False
    has_view = np.zeros(len(valid), bool)
    has_view[[f for f in lidar_views if 0 <= f < len(valid)]] = True
    for step in (1, -1):
        posed = np.flatnonzero(valid)
        edge = int(posed[-1] if step > 0 else posed[0])
        for _ in range(max_frames):
            frame = edge + step
            target = lidar_views.get(frame)
            if target is None or not 0 <= frame < len(valid) or valid[frame] or abs(times[frame] - times[edge]) >= max_gap:
                break
            near = nearest_posed(valid & has_view, times, frame, neighbours)
            if not near:
                break
            source = np.concatenate([transform_points(invert_pose(poses[f]), lidar_views[f]) for f in near])
            # The whole views' centroids shift with the instance from frame to frame (no camera
            # cuts them): a car overtaking from behind gains speed, and the velocity of the two
            # sliver views it first showed the cameras put the frame before them 2 m off.
            prediction = poses[near[0]].copy()
            prediction[:3, 3] += target.mean(0) - lidar_views[near[0]].mean(0)
            pose = motion_prior_pose(prediction, source, target, registration)
            visibility = None
            if sensors is not None:
                source_sensors = np.repeat(sensors_in_canonical(poses, sensors, np.asarray(near)),
                                           [len(lidar_views[f]) for f in near], axis=0)
                visibility = Visibility.of(source, source_sensors, sensors[frame], registration.back_face_tolerance)
            fit = registration_fitness(pose, source, target, registration.inlier_distance, visibility)
            fitness[frame] = max(fitness[frame], fit)
            if (fit < registration.fitness_threshold or not upright(pose[:3, :3], registration.max_tilt)
                    or np.linalg.norm(pose[:3, 3] - prediction[:3, 3]) > max_deviation):
                break
            poses[frame], valid[frame], counts[frame] = pose, True, len(target)
            edge, extended = frame, True
    if not extended:
        return track
    return replace(track, poses=fill_invalid_poses(poses, valid), valid=valid, fitness=fitness, point_counts=counts)
