"""Per-instance trajectories from lidar registration (paper Sec. 3.3).

The canonical frame of an instance is the centre of the axis-aligned box of its points at the frame
with the most points, with identity rotation. The other frames, in decreasing order of point count,
are registered against the growing canonical point set; a success gives that frame's pose and adds
its points (mapped back to the canonical frame) to the set. The ``centroid`` method is the paper's
ablation (c): translation only, from the points' centroids.

Ours, each with a switch in :class:`TrajectoryConfig` (docs/instances.md describes them):
frames that fail are registered again against their nearest registered neighbours, gated by a
constant-velocity prediction; half-turned registrations are turned back (heading_flips.py);
points landing on surfaces that face away from the sensor are not inliers (registration.py); and
observations no registration reached are registered among themselves and linked back through the
vehicle's box (segment_linking.py), or become an instance of their own.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Literal, Optional

import numpy as np
from tqdm import tqdm

from idsplat_ns.data.geometry import invert_pose, transform_points
from idsplat_ns.data.scene import Scene
from idsplat_ns.instances.amodal_centre import amodal_centre, sensors_in_canonical, travel_direction, typical_size
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.heading_flips import HeadingFlipConfig, canonical_box_centre, heading_errors, turn_about
from idsplat_ns.instances.lifting import InstanceObservation, LiftedInstances
from idsplat_ns.instances.motion_prior import (
    centroid_velocity, motion_outliers, motion_prior_pose, predicted_pose, prediction_gate,
)  # fmt: skip
from idsplat_ns.instances.registration import (
    RegistrationConfig,
    Visibility,
    icp_point_to_plane,
    register,
    registration_fitness,
    upright,
)
from idsplat_ns.instances.segment_linking import SegmentLinkConfig, link_segment
from idsplat_ns.instances.static_conversion import StaticConversionConfig, is_stationary
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
    min_segment_frames: int = 3
    """Ours: observations of a mask instance that no registration reached form a new instance of
    their own when at least this many of them register together (a turning car seen from the
    front, then only from behind, shares no surface between the two views). The paper keeps one
    instance per mask ID and drops them. 0 disables."""
    chain_neighbours: int = 3
    """Ours: a frame that fails against the whole canonical set is registered again against the
    canonical points of only its (up to) this many nearest registered frames in time, outwards
    from the registered ones. A turning car shows other faces than in its dense frames, so the
    whole set scores below the fitness threshold while its neighbours' view matches. 0: the
    paper's single pass."""
    chain_max_gap: float = 1.0
    """Seconds: neighbours further away in time are not used by the chained registration."""
    chain_max_deviation: float = 1.0
    """Metres: a chained registration is accepted only this close to the constant-velocity
    prediction from the two nearest registered frames."""
    chain_centroid_velocity: bool = True
    """Ours, with the chain only: beside the only registered frame, predict with the velocity of
    the observations' centroids (least squares over a second either side) instead of none. The
    densest view of a car passing the ego is its nearest; its neighbours, 2 m away at 10 m/s and
    0.2 s, never fell within ``chain_max_deviation`` of a zero-velocity prediction."""
    chain_gate_grows: bool = True
    """Ours, with the chain only: a prediction extrapolated from two registered frames close in
    time may be off by more than ``chain_max_deviation``: the gate grows by the velocity error
    that that deviation in either frame makes over their baseline, times the time extrapolated
    (motion_prior.prediction_gate). Two frames 0.2 s apart, one slid 1.1 m along a car's flat
    side, put the frame before them 1.7 m from the prediction."""
    motion_outliers: bool = True
    """Ours, with the chain only: before chaining, first-pass registrations further than
    ``chain_max_deviation`` from the constant-velocity prediction of their two nearest registered
    frames are dropped (worst first, one at a time) and left to the chained registration, which
    starts from the motion. A car entering the view showed only its front, which registered onto
    the rear of the canonical set 3.5 m ahead of itself at fitness 1.0."""
    coast_frames: int = 1
    """Ours, with the chain only: up to this many observed frames just past either end of the
    registered frames that no registration reached take the constant-velocity prediction as their
    pose when their points fit it (the registration fitness against the nearest registered frames'
    canonical points). Their points do not join the canonical set. A car leaving the camera's view
    is lifted cut at the image border; registration slides that cut onto the car's real end,
    metres from where it is, and the instance ended a frame early while the images still show it.
    0 disables."""
    heading_flips: HeadingFlipConfig = field(default_factory=HeadingFlipConfig)
    """Registrations whose heading disagrees with the direction of travel (front/back flips,
    quarter turns), turned back (ours; see instances/heading_flips.py)."""
    link_segments: SegmentLinkConfig = field(default_factory=SegmentLinkConfig)
    """Split segments joined back to their instance through the vehicle's box (ours; see
    instances/segment_linking.py). Needs the sensor positions (lidar sweeps)."""


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
    times: Optional[np.ndarray] = None,  # [F] seconds; needed for heading correction
    source_id: Optional[int] = None,
    sensor_positions: Optional[np.ndarray] = None,  # [F, 3] world; where the lidar was at each frame
) -> InstanceTrack:
    """Poses of one instance at every frame where registration succeeds. ``source_id`` is the mask
    instance whose lifted points and features these are (default ``iid``). ``sensor_positions``
    place the turn of a heading correction about the whole vehicle's centre, not the seen part's."""
    fid = iid if source_id is None else source_id
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
        return None if features is None or not features.colors else features.colors.get((fid, o.frame))

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
            canon_frames.append(o.frame)
    else:
        if features is None:
            raise ValueError("registration needs point features (pass the extractor's output, or use method='centroid')")
        canon_feat = [_obs_features(features, fid, ref)]

        def accept(o: InstanceObservation, transform: np.ndarray) -> None:
            poses[o.frame], valid[o.frame] = transform, True
            canon_pts.append(transform_points(invert_pose(transform), o.points))
            canon_feat.append(_obs_features(features, fid, o))
            canon_cols.append(colours_of(o))
            canon_frames.append(o.frame)

        for o in order[1:]:
            result = register(np.concatenate(canon_pts), np.concatenate(canon_feat), o.points,
                              _obs_features(features, fid, o), config.registration,
                              _chunk_sensors(poses, canon_frames, canon_pts, range(len(canon_pts)), sensor_positions),
                              _sensor_at(sensor_positions, o.frame))
            fitness[o.frame] = result.fitness
            if result.success:
                accept(o, result.transform)
        if config.chain_neighbours > 0 and times is not None:
            # Outliers twice: the first pass's slides, then the chain's own (its first frames lean
            # on the densest view, which may itself be the slid one). The chain runs again only
            # when the second pass dropped a frame: with nothing changed it would retry the same
            # registrations (deterministic) and fail them again.
            for again in (False, True) if config.motion_outliers else (False,):
                dropped = motion_outliers(poses, canon_frames, times, config.chain_max_deviation) if config.motion_outliers else []
                for f in dropped:
                    k = canon_frames.index(f)
                    del canon_pts[k], canon_feat[k], canon_cols[k], canon_frames[k]
                    valid[f] = False
                if again and not dropped:
                    break
                _register_chain(observations, poses, valid, fitness, canon_pts, canon_feat, canon_frames, times, config,
                                lambda o: _obs_features(features, fid, o), accept, sensor_positions)
        if config.heading_flips.enabled and times is not None:
            by_frame = {o.frame: o for o in observations}
            _correct_headings(poses, valid, fitness, counts, canon_pts, canon_cols, canon_frames, by_frame, times, config,
                              label, sensor_positions)
        if config.chain_neighbours > 0 and config.coast_frames > 0 and times is not None:
            _coast_ends(observations, poses, valid, fitness, canon_pts, canon_frames, times, config, sensor_positions)
    colors = None if any(c is None for c in canon_cols) else np.concatenate(canon_cols)
    point_frames = np.concatenate([np.full(len(p), f, np.int32) for p, f in zip(canon_pts, canon_frames)])
    # Every chunk is its frame's whole observation, in order, so the ray times line up.
    by_frame_obs = {o.frame: o for o in observations}
    point_times = None
    if all(by_frame_obs[f].times is not None for f in canon_frames):
        point_times = np.concatenate([by_frame_obs[f].times for f in canon_frames])
        if len(point_times) != len(point_frames):  # a chunk that is not a whole observation: a bug
            raise ValueError(f"instance {iid}: canonical chunks do not match their observations' ray times")
    return InstanceTrack(
        instance_id=iid, label=label, canonical_points=np.concatenate(canon_pts), canonical_colors=colors,
        poses=fill_invalid_poses(poses, valid), valid=valid, point_counts=counts, fitness=fitness,
        canonical_frame=int(ref.frame), point_frames=point_frames, point_times=point_times,
    )


def _chunk_sensors(
    poses: np.ndarray,  # [F, 4, 4] canonical -> world
    canon_frames: list[int],  # the frame of each canonical chunk
    canon_pts: list[np.ndarray],  # the chunks
    chunks: Iterable[int],  # which chunks, in the order their points are concatenated
    sensor_positions: Optional[np.ndarray],  # [F, 3] world
) -> Optional[np.ndarray]:  # -> [N, 3] canonical
    """The sensor that saw each point of ``chunks``, in the canonical frame (a chunk is its
    frame's points mapped by that frame's pose, so the same pose maps its sensor)."""
    if sensor_positions is None:
        return None
    chunks = list(chunks)
    frames = np.asarray([canon_frames[k] for k in chunks], dtype=np.int64)
    local = sensors_in_canonical(poses, sensor_positions, frames)  # [K, 3]
    return np.repeat(local, [len(canon_pts[k]) for k in chunks], axis=0)


def _sensor_at(sensor_positions: Optional[np.ndarray], frame: int) -> Optional[np.ndarray]:  # -> [3] world
    return None if sensor_positions is None else sensor_positions[frame]


def _nearest_chunks(
    canon_frames: list[int],  # the frame of each canonical chunk
    times: np.ndarray,  # [F] seconds
    frame: int,
    count: int,
    max_gap: float = np.inf,  # seconds
) -> list[int]:
    """Indices of the (up to) ``count`` chunks nearest to ``frame`` in time, nearest first (ties in
    chunk order), leaving out those further than ``max_gap``."""
    gaps = np.abs(times[np.asarray(canon_frames)] - times[frame])
    return [int(k) for k in np.argsort(gaps, kind="stable")[:count] if gaps[k] <= max_gap]


def _register_chain(
    observations: list[InstanceObservation],
    poses: np.ndarray,  # [F, 4, 4] (updated through ``accept``)
    valid: np.ndarray,  # [F] bool (updated through ``accept``)
    fitness: np.ndarray,  # [F] (updated in place)
    canon_pts: list[np.ndarray],
    canon_feat: list[np.ndarray],
    canon_frames: list[int],
    times: np.ndarray,  # [F] seconds
    config: TrajectoryConfig,
    features_of,
    accept,
    sensor_positions: Optional[np.ndarray] = None,  # [F, 3] world
) -> None:
    """Register failed frames against their nearest registered neighbours' canonical points,
    nearest-in-time first, until no more succeed (see ``TrajectoryConfig.chain_neighbours``)."""
    tried: set[tuple[int, tuple[int, ...]]] = set()
    while True:
        pending = [o for o in observations if not valid[o.frame]]
        candidates = []
        for o in pending:
            near = _nearest_chunks(canon_frames, times, o.frame, config.chain_neighbours, config.chain_max_gap)
            key = (o.frame, tuple(sorted(canon_frames[k] for k in near)))
            if near and key not in tried:
                candidates.append((float(abs(times[canon_frames[near[0]]] - times[o.frame])), o, near, key))
        if not candidates:
            return
        succeeded = False
        for _, o, near, key in sorted(candidates, key=lambda c: (c[0], c[1].frame)):
            tried.add(key)
            source = np.concatenate([canon_pts[k] for k in near])
            source_sensors = _chunk_sensors(poses, canon_frames, canon_pts, near, sensor_positions)
            sensor = _sensor_at(sensor_positions, o.frame)
            result = register(source, np.concatenate([canon_feat[k] for k in near]), o.points, features_of(o),
                              config.registration, source_sensors, sensor)
            # Feature matches of a far car are weak: also start from the motion's prediction, and
            # accept only poses near it (a box registered to part of itself can slide metres).
            # The observations' velocity is read only beside a single registered frame.
            velocity, span = (centroid_velocity(observations, times, o.frame)
                              if config.chain_centroid_velocity and len(canon_frames) == 1 else (None, 0.0))
            prediction = predicted_pose(poses, canon_frames, times, o.frame, velocity)
            gate = (prediction_gate(canon_frames, times, o.frame, config.chain_max_deviation, span)
                    if config.chain_gate_grows else config.chain_max_deviation)
            prior = motion_prior_pose(prediction, source, o.points, config.registration)
            visibility = Visibility.of(source, source_sensors, sensor, config.registration.back_face_tolerance)
            prior_fit = registration_fitness(prior, source, o.points, config.registration.inlier_distance, visibility)
            fitness[o.frame] = max(fitness[o.frame], result.fitness, prior_fit)
            transform, fit = None, 0.0
            for candidate, score in ((result.transform, result.fitness if result.success else 0.0), (prior, prior_fit)):
                if (score > fit and np.linalg.norm(candidate[:3, 3] - prediction[:3, 3]) <= gate
                        and upright(candidate[:3, :3], config.registration.max_tilt)):
                    transform, fit = candidate, score
            if transform is not None and fit >= config.registration.fitness_threshold:
                accept(o, transform)
                succeeded = True
                break  # the neighbourhoods changed: recompute them
        if not succeeded:
            return


def _correct_headings(
    poses: np.ndarray,  # [F, 4, 4] (updated in place)
    valid: np.ndarray,  # [F] bool
    fitness: np.ndarray,  # [F] (updated in place)
    counts: np.ndarray,  # [F] lidar points per frame
    canon_pts: list[np.ndarray],  # canonical chunks, one per registered frame (updated in place)
    canon_cols: list[Optional[np.ndarray]],  # their colours (updated in place)
    canon_frames: list[int],  # the frame of each chunk (updated in place)
    by_frame: dict[int, InstanceObservation],
    times: np.ndarray,  # [F] seconds
    config: TrajectoryConfig,
    label: str = "",
    sensor_positions: Optional[np.ndarray] = None,  # [F, 3] world
) -> None:
    """Turn back registrations whose heading disagrees with the motion (see heading_flips.py): by
    the disagreement about the centre of the vehicle the agreeing canonical points show, refined
    by ICP on them, and re-map those frames' canonical points. A frame whose turned pose does not
    reach the fitness threshold either is dropped (it disagrees with the motion both ways)."""
    flips = config.heading_flips
    t = poses[valid, :3, 3]
    if len(t) < 2 or np.max(np.linalg.norm(t[:, None] - t[None], axis=-1)) < flips.min_track_displacement:
        return
    if flips.skip_stationary and is_stationary(list(by_frame.values()), StaticConversionConfig()):
        return
    error = heading_errors(times, poses, valid, counts, flips)
    wrong = np.isfinite(error)
    if not wrong.any():
        return
    keep = [k for k, f in enumerate(canon_frames) if not wrong[f]]
    reference = np.concatenate([canon_pts[k] for k in keep])
    # The reference's normals once; each turned frame is seen from its own sensor.
    visibility = Visibility.of(reference, _chunk_sensors(poses, canon_frames, canon_pts, keep, sensor_positions),
                               np.zeros(3), config.registration.back_face_tolerance)
    centre = _turn_centre(reference, poses, [canon_frames[k] for k in keep], label, sensor_positions)
    reg = config.registration
    for k, f in enumerate(canon_frames):
        if not wrong[f]:
            continue
        target = by_frame[f].points
        turned = turn_about(poses[f], centre, float(error[f]))
        refined = icp_point_to_plane(turned, reference, target, reg.icp_iterations, reg.icp_distance)
        if not upright(refined[:3, :3], reg.max_tilt):
            refined = turned
        seen_from = None if visibility is None else replace(visibility, target_sensor=sensor_positions[f])
        fit = registration_fitness(refined, reference, target, reg.inlier_distance, seen_from)
        if fit >= reg.fitness_threshold:
            poses[f], fitness[f] = refined, fit
            canon_pts[k] = transform_points(invert_pose(refined), target)
        else:
            valid[f] = False
    for k in reversed(range(len(canon_frames))):
        if not valid[canon_frames[k]]:
            del canon_pts[k], canon_cols[k], canon_frames[k]


def _coast_ends(
    observations: list[InstanceObservation],
    poses: np.ndarray,  # [F, 4, 4] (updated in place)
    valid: np.ndarray,  # [F] bool (updated in place)
    fitness: np.ndarray,  # [F] (updated in place)
    canon_pts: list[np.ndarray],  # canonical chunks, one per registered frame
    canon_frames: list[int],  # the frame of each chunk
    times: np.ndarray,  # [F] seconds
    config: TrajectoryConfig,
    sensor_positions: Optional[np.ndarray] = None,  # [F, 3] world
) -> None:
    """Give the observed frames just past the registered ones the constant-velocity prediction
    where their points fit it (see ``TrajectoryConfig.coast_frames``). Predictions come from the
    registered frames only, so one coasted frame never carries the next."""
    if len(canon_frames) < 2:
        return  # no velocity
    by_frame = {o.frame: o for o in observations}
    registered = sorted(canon_frames)
    reg = config.registration
    for start, step in ((registered[-1], 1), (registered[0], -1)):
        for k in range(1, config.coast_frames + 1):
            f = start + step * k
            o = by_frame.get(f)
            if o is None or valid[f] or len(o.points) < config.min_points:
                break
            if abs(times[f] - times[start]) > config.chain_max_gap:
                break
            near = _nearest_chunks(canon_frames, times, f, config.chain_neighbours)
            source = np.concatenate([canon_pts[j] for j in near])
            prediction = predicted_pose(poses, canon_frames, times, f)
            visibility = Visibility.of(source, _chunk_sensors(poses, canon_frames, canon_pts, near, sensor_positions),
                                       _sensor_at(sensor_positions, f), reg.back_face_tolerance)
            fit = registration_fitness(prediction, source, o.points, reg.inlier_distance, visibility)
            fitness[f] = max(fitness[f], fit)
            if fit < reg.fitness_threshold:
                break
            poses[f], valid[f] = prediction, True


def _turn_centre(
    reference: np.ndarray,  # [N, 3] canonical points of the frames whose heading agrees
    poses: np.ndarray,  # [F, 4, 4] canonical -> world
    frames: list[int],  # the frames of those points
    label: str,
    sensor_positions: Optional[np.ndarray],  # [F, 3] world, or None
) -> np.ndarray:  # -> [3] canonical
    """Where a wrong heading is turned about: the amodal centre of the vehicle (amodal_centre.py)
    when the class and the sensor positions are known, else the middle of the points' box. A turn
    by 180° about a point ``d`` from the true centre misplaces the turned frames by ``2 d``: on the
    small street (seed 5) a car passing beside the sensor showed one side only, the middle of its
    points sat 0.9 m from its centre, and its 10 turned far frames were 1.8 m off."""
    fallback = canonical_box_centre(reference)
    size = typical_size(label) if label else None
    if sensor_positions is None or size is None or len(frames) < 2:
        return fallback
    mask = np.zeros(len(poses), bool)
    mask[frames] = True
    forward = travel_direction(poses, mask)
    if forward is None:
        return fallback
    sensors = sensors_in_canonical(poses, sensor_positions, np.asarray(sorted(frames)))
    return amodal_centre(reference, forward, sensors, size[0], size[1])


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
    times = np.asarray(scene.frame_times, np.float64)
    sensors = scene.lidar_positions() if getattr(scene, "lidar", None) else None  # [F, 3]
    next_id = max((iid for iid, _ in items), default=0) + 1
    split_from: dict[int, int] = {}
    linked_into: dict[str, list[int]] = {}  # instance -> frames of each segment linked back into it
    for iid, obs in tqdm(items, desc="registration", disable=not progress):
        if not obs or max(len(o.points) for o in obs) < config.min_points:
            continue
        track = estimate_instance_track(iid, lifted.labels[iid], obs, features, scene.num_frames, config, times,
                                        sensor_positions=sensors)
        segments = []
        rest = [o for o in obs if not track.valid[o.frame]]
        # Frames no registration reached may still agree among themselves (a car seen from the
        # front, then only from behind): they are linked back through the vehicle's box, or
        # become an instance of their own.
        while config.method == "registration" and config.min_segment_frames > 0 and len(rest) >= config.min_segment_frames:
            segment = estimate_instance_track(next_id, lifted.labels[iid], rest, features, scene.num_frames, config,
                                              times, source_id=iid, sensor_positions=sensors)
            if segment.num_valid < config.min_segment_frames:
                break
            rest = [o for o in rest if not segment.valid[o.frame]]
            linked = None
            if config.link_segments.enabled and sensors is not None:
                linked = link_segment(track, segment, sensors, times, config.link_segments)
            if linked is not None:
                track = linked
                linked_into.setdefault(str(iid), []).append(int(segment.num_valid))
                continue
            segments.append(segment)
            split_from[next_id] = iid
            next_id += 1
        tracks.append(track)
        tracks.extend(segments)
    meta = {"trajectory_method": config.method, "features": None if features is None else features.extractor,
            "split_from": {str(k): v for k, v in split_from.items()}, "linked_segments": linked_into}
    return InstanceTracks(np.asarray(scene.frame_indices), np.asarray(scene.frame_times, np.float64), tracks, [], meta)
