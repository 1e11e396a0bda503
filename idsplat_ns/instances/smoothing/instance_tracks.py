"""Smoothing of registered tracks (paper Sec. 3.4) as the preprocessing runs it: each dynamic
instance's registrations placed at their points' ray times, with the translation covariances its
views allow, the heading prior of its box axis and the lidar ground under it, smoothed by the CT
model (smoother.py) and read back at the frame times, with its points re-posed at their own ray
times."""

from __future__ import annotations

from dataclasses import replace
from typing import Optional

import numpy as np

from idsplat_ns.data.geometry import interpolate_poses
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.amodal_centre import box_heading, travel_direction
from idsplat_ns.instances.ground import GroundSurface
from idsplat_ns.instances.process_pool import SMOOTHING_MIN_OBSERVATIONS, map_instances, resolve_workers
from idsplat_ns.instances.smoothing.config import SmoothingConfig
from idsplat_ns.instances.smoothing.observability import translation_covariances
from idsplat_ns.instances.smoothing.smoother import SmoothedTrajectory, smooth_trajectory
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks


def measurement_covariances(
    inst: InstanceTrack, num_frames: int, config: SmoothingConfig, has_heading: bool = False
) -> Optional[np.ndarray]:  # -> [F, 3, 3] or None
    """Translation covariance of each of ``inst``'s registrations from the surfaces its points show
    (smoothing/observability.py, with ``config``'s ``degenerate_*`` settings), or None (the
    paper's isotropic sigma) where that is switched off or the instance has no per-frame points.
    ``has_heading``: the smoother ties the instance's travel to its box axis (heading prior), so
    its sparse views' unmeasured directions can be left to the motion
    (``config.degenerate_sparse_frame_points``)."""
    if not config.degenerate_directions or inst.point_frames is None:
        return None
    return translation_covariances(
        inst.canonical_points, inst.point_frames, num_frames, config.measurement_trans_sigma,
        config.degenerate_ratio, config.degenerate_sigma, config.degenerate_min_anchor_frames,
        config.degenerate_min_frame_points, config.degenerate_min_facing_points, config.degenerate_one_sided,
        config.degenerate_vertical_sigma, config.degenerate_sparse_frame_points if has_heading else None)


def instance_heading(inst: InstanceTrack, min_points: int) -> Optional[np.ndarray]:  # -> [3] canonical, or None
    """The vehicle's box axis nearest its direction of travel, in the canonical frame, from the
    vertical faces of its registered points (``amodal_centre.box_heading``); None when it barely
    moves, has no per-frame points or fewer than ``min_points`` points."""
    forward = travel_direction(inst.poses, inst.valid)
    if forward is None or inst.point_frames is None or len(inst.canonical_points) < max(min_points, 3):
        return None
    return box_heading(inst.canonical_points, forward, inst.point_frames)


def registration_times(inst: InstanceTrack, frame_times: np.ndarray, config: SmoothingConfig) -> np.ndarray:  # [F] -> [F]
    """When each of ``inst``'s registrations is placed for smoothing: its points' mean ray time
    (``config.measurement_times``) or the frame time."""
    return inst.measurement_times(frame_times) if config.measurement_times else frame_times


def uses_ground(scene: Scene, config: SmoothingConfig) -> bool:
    """Whether the smoother keeps vehicles on the lidar ground: ``config`` asks for it and the
    scene has lidar."""
    return config.ground_height_walk_rate is not None and scene.has_lidar


def ground_surface(scene: Scene, config: SmoothingConfig) -> Optional[GroundSurface]:
    """The lidar ground the smoother keeps vehicles on, or None where :func:`uses_ground` says no."""
    return GroundSurface.from_sweeps(scene.lidar, config.ground) if uses_ground(scene, config) else None


def smooth_instance(inst: InstanceTrack, times: np.ndarray, config: SmoothingConfig,
                    ground: Optional[GroundSurface] = None) -> SmoothedTrajectory:
    """Smooth one instance's registrations placed at ``times`` [F] (seconds), with the translation
    covariances of its views, the heading prior of its box axis and the ``ground`` under it, as
    ``config`` asks."""
    heading = instance_heading(inst, config.heading_prior_min_points) if config.heading_prior_sigma is not None else None
    return smooth_trajectory(times, inst.poses, inst.valid, config,
                             measurement_covariances(inst, len(times), config, heading is not None), heading,
                             None if ground is None else ground.heights_at)


def smooth_tracks(tracks: InstanceTracks, config: SmoothingConfig, ground: Optional[GroundSurface] = None,
                  workers: int = 1, progress: bool = False) -> InstanceTracks:
    """Replace each dynamic instance's poses by smoothed ones at the frame times (valid within the
    measured span), in ``workers`` processes (0: one per core for a large scene; process_pool.py):
    the tracks do not depend on it.

    Each registration is placed at its points' mean ray time (``config.measurement_times``), not
    the frame's: the rays that hit a car are fired up to half a sweep away from the frame time,
    and a car at 12 m/s is 0.3 m elsewhere then (measured on the synthetic street). The poses are
    then read at the frame times from the CT model, and each point is re-posed with the pose at
    its own ray time (``config.repose_points``), which also undoes the car's motion during the
    sweep, as the oracle does with the annotated boxes.
    """
    times = np.asarray(tracks.frame_times, np.float64)
    sizes = [int(inst.num_valid) for inst in tracks.instances]
    out = map_instances(smooth_instance_track, (times, config, ground), tracks.instances,
                        resolve_workers(workers, len(sizes), sum(sizes), SMOOTHING_MIN_OBSERVATIONS), sizes, "smoothing",
                        progress)
    return replace(tracks, instances=out, metadata={**tracks.metadata, "smoothed": True})


def smooth_instance_track(
    shared: tuple[np.ndarray, SmoothingConfig, Optional[GroundSurface]],  # frame times [F], settings, ground
    inst: InstanceTrack,
) -> InstanceTrack:
    """One dynamic instance of :func:`smooth_tracks`, smoothed."""
    times, config, ground = shared
    meas = registration_times(inst, times, config)
    sm = smooth_instance(inst, meas, config, ground)
    lo, hi = sm.span
    slack = float(np.max(np.abs(meas - times)))  # frame times lie at most this far outside [lo, hi]
    valid = (meas >= lo) & (meas <= hi)
    frame_poses = np.array(sm.poses, dtype=np.float64, copy=True)  # states at the measurement times
    if slack > 0 and valid.any():
        valid = (times >= meas[valid].min() - slack) & (times <= meas[valid].max() + slack)
        for k in np.flatnonzero(valid):
            frame_poses[k] = sm.pose_at(float(times[k]), margin=slack)
    # Points of measurements the smoother rejects were placed by a wrong registration.
    inst = inst.keep_points_of_frames(sm.inliers) if config.drop_outlier_points else inst
    if config.repose_points and inst.point_frames is not None:
        inst = inst.with_points_posed_by(_poses_at_point_times(sm, inst, meas, slack))
    return replace(inst, poses=frame_poses, valid=valid, measured_valid=inst.valid)


def _poses_at_point_times(
    sm: SmoothedTrajectory,
    inst: InstanceTrack,
    meas: np.ndarray,  # [F] measurement times (seconds)
    slack: float,
    bins: int = 5,
) -> np.ndarray:  # [N, 4, 4] canonical -> world at each canonical point's ray time
    """The smoothed pose at each canonical point's ray time (its frame's measurement time where
    ray times are unknown): the CT model read at ``bins`` times across each frame's rays, and
    interpolated between them (a sweep is short: the motion is smooth over it)."""
    out = np.empty((len(inst.canonical_points), 4, 4))
    t_of_point = meas[inst.point_frames] if inst.point_times is None else inst.point_times
    margin = slack + 0.1  # a frame's rays may lie up to a sweep (0.1 s) from its end measurement's mean time
    for f in np.unique(inst.point_frames):
        rows = np.flatnonzero(inst.point_frames == f)
        t = t_of_point[rows]
        grid = np.linspace(t.min(), t.max(), bins) if t.max() > t.min() else t[:1]
        poses = [sm.pose_at(float(g), margin=margin) for g in grid]
        poses = np.stack([p if p is not None else sm.poses[f] for p in poses])
        out[rows] = poses[0] if len(grid) == 1 else interpolate_poses(grid, poses, t, extrapolate=True)
    return out
