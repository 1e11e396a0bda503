"""Per-instance trajectories from lidar registration (paper Sec. 3.3).

Each instance's track is built by :mod:`~idsplat_ns.instances.trajectory_passes` on a
:class:`~idsplat_ns.instances.track_builder.TrackBuilder`: the canonical frame is the centre of the
axis-aligned box of its points at the frame with the most points, with identity rotation; the
other frames, in decreasing order of point count, are registered against the growing canonical
point set, and our passes follow. Observations no registration reached are then registered among
themselves and linked back through the vehicle's box (segment_linking.py), or become an instance
of their own. Last, the track is carried through the frames where only the lidar saw it
(out_of_view.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.lifting import InstanceObservation, LiftedInstances
from idsplat_ns.instances.out_of_view import extend_out_of_view
from idsplat_ns.instances.process_pool import REGISTRATION_MIN_OBSERVATIONS, map_instances, resolve_workers
from idsplat_ns.instances.segment_linking import link_segment
from idsplat_ns.instances.track_builder import TrackBuilder
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks
# Run folders' config.yml name the settings class here, where it was defined until it got a module of its own.
from idsplat_ns.instances.trajectory_config import TrajectoryConfig, config_for_label
from idsplat_ns.instances.trajectory_passes import build_track

__all__ = ["TrajectoryConfig", "estimate_instance_track", "estimate_trajectories"]


def estimate_instance_track(
    iid: int,
    label: str,
    observations: list[InstanceObservation],
    features: Optional[PointFeatures],
    num_frames: int,
    config: TrajectoryConfig,
    times: Optional[np.ndarray] = None,  # [F] seconds; needed by every pass beyond the paper's
    source_id: Optional[int] = None,
    sensor_positions: Optional[np.ndarray] = None,  # [F, 3] world; where the lidar was at each frame
) -> InstanceTrack:
    """Poses of one instance at every frame where registration succeeds. ``source_id`` is the mask
    instance whose lifted points and features these are (default ``iid``). ``sensor_positions``
    place the turn of a heading correction about the whole vehicle's centre, not the seen part's."""
    builder = TrackBuilder.start(iid, label, observations, num_frames, features, times, sensor_positions, source_id)
    return build_track(builder, config).track()


@dataclass(frozen=True)
class _SceneInputs:
    """What every instance's registration reads (sent once to each worker process)."""

    num_frames: int
    config: TrajectoryConfig
    times: np.ndarray  # [F] seconds
    sensors: Optional[np.ndarray]  # [F, 3] world


@dataclass(frozen=True)
class _InstanceJob:
    """One instance's observations and their features (picklable: it may run in another process)."""

    iid: int
    label: str
    observations: list[InstanceObservation]
    features: Optional[PointFeatures]  # this instance's only
    lidar_views: Mapping[int, np.ndarray] = field(default_factory=dict)  # frame -> [N, 3] world: all its lidar points


def _instance_tracks(scene: _SceneInputs, job: _InstanceJob) -> tuple[InstanceTrack, list[InstanceTrack], list[int]]:
    """The instance's track, the segments split off it (instance ids to be given by the caller) and
    the frame counts of the segments linked back into it."""
    config, obs = config_for_label(scene.config, job.label), job.observations
    track = estimate_instance_track(job.iid, job.label, obs, job.features, scene.num_frames, config, scene.times,
                                    sensor_positions=scene.sensors)
    segments, linked_frames = [], []
    rest = [o for o in obs if not track.valid[o.frame]]
    # Frames no registration reached may still agree among themselves (a car seen from the
    # front, then only from behind): they are linked back through the vehicle's box, or
    # become an instance of their own.
    while config.method == "registration" and config.min_segment_frames > 0 and len(rest) >= config.min_segment_frames:
        segment = estimate_instance_track(-1, job.label, rest, job.features, scene.num_frames, config, scene.times,
                                          source_id=job.iid, sensor_positions=scene.sensors)
        if segment.num_valid < config.min_segment_frames:
            break
        rest = [o for o in rest if not segment.valid[o.frame]]
        linked = None
        if config.link_segments.enabled and scene.sensors is not None:
            linked = link_segment(track, segment, scene.sensors, scene.times, config.link_segments)
        if linked is not None:
            track = linked
            linked_frames.append(int(segment.num_valid))
            continue
        segments.append(segment)
    if config.method == "registration" and config.chain_neighbours > 0:
        track = extend_out_of_view(track, job.lidar_views, scene.times, config.registration, config.out_of_view_frames,
                                   config.chain_neighbours, config.chain_max_gap, config.chain_max_deviation, scene.sensors)
    return track, segments, linked_frames


def estimate_trajectories(
    scene: Scene,
    lifted: LiftedInstances,
    features: Optional[PointFeatures],
    config: TrajectoryConfig = TrajectoryConfig(),
    progress: bool = True,
    workers: int = 1,
    lidar_views: Optional[Mapping[int, Mapping[int, np.ndarray]]] = None,
) -> InstanceTracks:
    """Trajectories of every lifted instance (before static conversion and smoothing), registered
    in ``workers`` processes (0: one per core for a large scene; process_pool.py): the tracks do
    not depend on it. ``lidar_views`` (per instance, frame -> [N, 3] world points of all its lidar
    returns; lidar_motion_lifting.load_lidar_views) are what ``config.out_of_view_frames`` carries
    an instance through where no camera saw it."""
    items = [(iid, obs) for iid, obs in sorted(lifted.observations.items())
             if obs and max(len(o.points) for o in obs) >= config.min_points]
    times = np.asarray(scene.frame_times, np.float64)
    sensors = scene.lidar_positions() if getattr(scene, "lidar", None) else None  # [F, 3]
    # The whole lidar views only where they are read: every cluster of every frame, pickled to each worker.
    views = lidar_views if lidar_views is not None and config.out_of_view_frames > 0 else {}
    jobs = [_InstanceJob(iid, lifted.labels[iid], obs, None if features is None else features.of_instance(iid),
                         views.get(iid, {})) for iid, obs in items]
    workers = resolve_workers(workers, len(jobs), sum(len(obs) for _, obs in items), REGISTRATION_MIN_OBSERVATIONS)
    # Largest first by points, not frames: a truck's 68 views of 7,000 points took 86 s of a
    # segment's 179, while 200 views of a car took 14 s.
    points = [sum(len(o.points) for o in obs) for _, obs in items]
    results = map_instances(_instance_tracks, _SceneInputs(scene.num_frames, config, times, sensors), jobs, workers,
                            points, "registration", progress)
    tracks = []
    next_id = max(lifted.observations, default=0) + 1
    split_from: dict[int, int] = {}
    linked_into: dict[str, list[int]] = {}  # instance -> frames of each segment linked back into it
    for (iid, _), (track, segments, linked_frames) in zip(items, results):
        if linked_frames:
            linked_into[str(iid)] = linked_frames
        tracks.append(track)
        for segment in segments:
            tracks.append(replace(segment, instance_id=next_id))
            split_from[next_id] = iid
            next_id += 1
    meta = {"trajectory_method": config.method, "features": None if features is None else features.extractor,
            "split_from": {str(k): v for k, v in split_from.items()}, "linked_segments": linked_into}
    return InstanceTracks(np.asarray(scene.frame_indices), np.asarray(scene.frame_times, np.float64), tracks, [], meta)
