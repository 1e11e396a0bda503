"""The passes that build an instance's track, in the order they run (:data:`TRACK_PASSES`).

The first is the paper's: the frames, densest first, registered against the growing canonical
set (or, for its ablation (c), placed by their points' centroids). The others are ours, each
switched off by one setting of :class:`~idsplat_ns.instances.trajectory_config.TrajectoryConfig`
(``docs/instances.md`` describes them; ``bench/bench_rule_ablation.py`` measures each one off):
frames that fail are registered again against their nearest registered neighbours, gated by a
constant-velocity prediction, after first-pass registrations the motion disagrees with are
dropped; half-turned registrations are turned back (heading_flips.py); frames just past either
end take the motion's prediction where their points fit it. A pass reads and changes the track
only through :class:`~idsplat_ns.instances.track_builder.TrackBuilder`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Optional

import numpy as np

from idsplat_ns.instances.amodal_centre import amodal_centre, sensors_in_canonical, travel_direction, typical_size
from idsplat_ns.instances.heading_flips import canonical_box_centre, heading_errors, turn_about
from idsplat_ns.instances.motion_prior import (
    centroid_velocity, motion_outliers, motion_prior_pose, predicted_pose, prediction_gate,
)  # fmt: skip
from idsplat_ns.instances.registration import Visibility, icp_point_to_plane, register, registration_fitness, upright
from idsplat_ns.instances.static_conversion import StaticConversionConfig, is_stationary
from idsplat_ns.instances.track_builder import TrackBuilder
from idsplat_ns.instances.trajectory_config import TrajectoryConfig


def densest_first(b: TrackBuilder) -> list:
    """The observations other than the reference, by decreasing point count (ties by frame)."""
    order = sorted(b.observations.values(), key=lambda o: (-len(o.points), o.frame))
    return [o for o in order if o.frame != b.reference_frame]


def place_by_centroids(b: TrackBuilder, config: TrajectoryConfig) -> None:
    """Ablation (c): every frame translated from the reference by its points' centroid shift."""
    ref_centroid = b.observations[b.reference_frame].points.mean(0)
    centre = b.poses[b.reference_frame, :3, 3]
    for o in densest_first(b):
        pose = np.eye(4)
        pose[:3, 3] = centre + (o.points.mean(0) - ref_centroid)
        b.accept(o, pose)
        b.fitness[o.frame] = 1.0


def _cut(b: TrackBuilder, o, config: TrajectoryConfig) -> bool:
    """Whether the observation is a long vehicle's view of which the cameras kept less than
    ``first_pass_min_seen_fraction`` (see ``cut_view_min_vehicle_length``)."""
    least = config.first_pass_min_seen_fraction
    if least is None or o.seen_fraction is None or o.seen_fraction >= least:
        return False
    size = typical_size(b.label) if b.label else None
    return size is not None and size[0] >= config.cut_view_min_vehicle_length


def _register_against_all(b: TrackBuilder, observations: list, config: TrajectoryConfig) -> None:
    """Each observation, in order, registered against the whole canonical set (growing)."""
    for o in observations:
        result = register(b.points(), b.chunk_features(), o.points, b.features_of(o.frame), config.registration,
                          b.chunk_sensors(), b.sensor_at(o.frame))
        b.fitness[o.frame] = result.fitness
        if result.success:
            b.accept(o, result.transform)


def register_densest_first(b: TrackBuilder, config: TrajectoryConfig) -> None:
    """The paper's pass: each frame, densest first, registered against the whole canonical set;
    with the chain, views the cameras cut are left to it (``TrajectoryConfig.first_pass_min_seen_fraction``)."""
    if b.features is None:
        raise ValueError("registration needs point features (pass the extractor's output, or use method='centroid')")
    chained = config.chain_neighbours > 0 and b.times is not None
    _register_against_all(b, [o for o in densest_first(b) if not (chained and _cut(b, o, config))], config)


def chain_registrations(b: TrackBuilder, config: TrajectoryConfig) -> None:
    """Frames that failed, registered against their nearest registered neighbours; with
    ``motion_outliers``, first-pass registrations the motion disagrees with are dropped first and
    left to the chain. Views the cameras cut that the chain could not place then get the paper's
    whole-set registration. Outliers twice: the first pass's slides, then the chain's own (its first
    frames lean on the densest view, which may itself be the slid one). The chain runs again only
    when the second look dropped a frame: with nothing changed it would retry the same
    registrations (deterministic) and fail them again."""
    for again in (False, True) if config.motion_outliers else (False,):
        dropped = motion_outliers(b.poses, b.frames, b.times, config.chain_max_deviation) if config.motion_outliers else []
        for f in dropped:
            b.drop(f)
        if again and not dropped:
            break
        _chain_once(b, config)
        if not again:  # cut views the chain could not place: the paper's registration, then the second look
            _register_against_all(b, [o for o in densest_first(b) if not b.valid[o.frame] and _cut(b, o, config)], config)


def _chain_once(b: TrackBuilder, config: TrajectoryConfig) -> None:
    """Register failed frames against their nearest registered neighbours' canonical points,
    nearest-in-time first, until no more succeed (see ``TrajectoryConfig.chain_neighbours``)."""
    tried: set[tuple[int, tuple[int, ...]]] = set()
    reg = config.registration
    while True:
        candidates = []
        for o in b.pending():
            near = b.nearest_chunks(o.frame, config.chain_neighbours, config.chain_max_gap)
            key = (o.frame, tuple(sorted(b.chunks[k].frame for k in near)))
            if near and key not in tried:
                candidates.append((float(abs(b.times[b.chunks[near[0]].frame] - b.times[o.frame])), o, near, key))
        if not candidates:
            return
        for _, o, near, key in sorted(candidates, key=lambda c: (c[0], c[1].frame)):
            tried.add(key)
            source = b.points(near)
            source_sensors = b.chunk_sensors(near)
            sensor = b.sensor_at(o.frame)
            result = register(source, b.chunk_features(near), o.points, b.features_of(o.frame), reg, source_sensors, sensor)
            # Feature matches of a far car are weak: also start from the motion's prediction, and
            # accept only poses near it (a box registered to part of itself can slide metres).
            # The observations' velocity is read only beside a single registered frame.
            velocity, span = (centroid_velocity(list(b.observations.values()), b.times, o.frame)
                              if config.chain_centroid_velocity and len(b.chunks) == 1 else (None, 0.0))
            prediction = predicted_pose(b.poses, b.frames, b.times, o.frame, velocity)
            gate = (prediction_gate(b.frames, b.times, o.frame, config.chain_max_deviation, span)
                    if config.chain_gate_grows else config.chain_max_deviation)
            prior = motion_prior_pose(prediction, source, o.points, reg)
            visibility = Visibility.of(source, source_sensors, sensor, reg.back_face_tolerance)
            prior_fit = registration_fitness(prior, source, o.points, reg.inlier_distance, visibility)
            b.fitness[o.frame] = max(b.fitness[o.frame], result.fitness, prior_fit)
            transform, fit = None, 0.0
            for candidate, score in ((result.transform, result.fitness if result.success else 0.0), (prior, prior_fit)):
                if (score > fit and np.linalg.norm(candidate[:3, 3] - prediction[:3, 3]) <= gate
                        and upright(candidate[:3, :3], reg.max_tilt)):
                    transform, fit = candidate, score
            if transform is not None and fit >= reg.fitness_threshold:
                b.accept(o, transform)
                break  # the neighbourhoods changed: recompute them
        else:
            return  # no candidate succeeded


def correct_headings(b: TrackBuilder, config: TrajectoryConfig) -> None:
    """Turn back registrations whose heading disagrees with the motion (see heading_flips.py): by
    the disagreement about the centre of the vehicle the agreeing canonical points show, refined
    by ICP on them, and re-map those frames' canonical points. A frame whose turned pose does not
    reach the fitness threshold either is dropped (it disagrees with the motion both ways)."""
    flips = config.heading_flips
    t = b.poses[b.valid, :3, 3]
    if len(t) < 2 or np.max(np.linalg.norm(t[:, None] - t[None], axis=-1)) < flips.min_track_displacement:
        return
    if flips.skip_stationary and is_stationary(list(b.observations.values()), StaticConversionConfig()):
        return
    error = heading_errors(b.times, b.poses, b.valid, b.point_counts, flips)
    wrong = np.isfinite(error)
    if not wrong.any():
        return
    keep = [k for k, c in enumerate(b.chunks) if not wrong[c.frame]]
    reference = b.points(keep)
    # The reference's normals once; each turned frame is seen from its own sensor.
    visibility = Visibility.of(reference, b.chunk_sensors(keep), np.zeros(3), config.registration.back_face_tolerance)
    centre = turn_centre(reference, b.poses, [b.chunks[k].frame for k in keep], b.label, b.sensor_positions)
    reg = config.registration
    for f in [c.frame for c in b.chunks if wrong[c.frame]]:
        target = b.observations[f].points
        turned = turn_about(b.poses[f], centre, float(error[f]))
        refined = icp_point_to_plane(turned, reference, target, reg.icp_iterations, reg.icp_distance)
        if not upright(refined[:3, :3], reg.max_tilt):
            refined = turned
        seen_from = None if visibility is None else replace(visibility, target_sensor=b.sensor_positions[f])
        fit = registration_fitness(refined, reference, target, reg.inlier_distance, seen_from)
        if fit >= reg.fitness_threshold:
            b.repose(f, refined, fit)
        else:
            b.drop(f)


def turn_centre(
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


def coast_ends(b: TrackBuilder, config: TrajectoryConfig) -> None:
    """Give the observed frames just past the registered ones the constant-velocity prediction
    where their points fit it (see ``TrajectoryConfig.coast_frames``). Predictions come from the
    registered frames only, so one coasted frame never carries the next."""
    if len(b.chunks) < 2:
        return  # no velocity
    registered = sorted(b.frames)
    reg = config.registration
    for start, step in ((registered[-1], 1), (registered[0], -1)):
        for k in range(1, config.coast_frames + 1):
            f = start + step * k
            o = b.observations.get(f)
            if o is None or b.valid[f] or len(o.points) < config.min_points:
                break
            if abs(b.times[f] - b.times[start]) > config.chain_max_gap:
                break
            near = b.nearest_chunks(f, config.chain_neighbours)
            source = b.points(near)
            prediction = predicted_pose(b.poses, b.frames, b.times, f)
            visibility = Visibility.of(source, b.chunk_sensors(near), b.sensor_at(f), reg.back_face_tolerance)
            fit = registration_fitness(prediction, source, o.points, reg.inlier_distance, visibility)
            b.fitness[f] = max(b.fitness[f], fit)
            if fit < reg.fitness_threshold:
                break
            b.coast(f, prediction)


@dataclass(frozen=True)
class TrackPass:
    """One pass of the track builder and when it runs."""

    name: str  # as docs/instances.md and the rule ablation name it
    run: Callable[[TrackBuilder, TrajectoryConfig], None]
    runs_when: Callable[[TrajectoryConfig, bool], bool]  # (config, the frame times are known)
    switch: Optional[tuple[str, object]]  # (dotted TrajectoryConfig field, value) that switches it off; None: the paper's
    what: str


TRACK_PASSES: tuple[TrackPass, ...] = (
    TrackPass("centroid", place_by_centroids, lambda c, timed: c.method == "centroid", None,
              "ablation (c): translation only, from the points' centroids"),
    TrackPass("registration", register_densest_first, lambda c, timed: c.method == "registration", None,
              "the paper's: frames densest first, registered against the growing canonical set"),
    TrackPass("chain", chain_registrations,
              lambda c, timed: c.method == "registration" and c.chain_neighbours > 0 and timed,
              ("chain_neighbours", 0),
              "failed frames registered again against their nearest registered frames (with motion-outliers and coast)"),
    TrackPass("heading-flips", correct_headings,
              lambda c, timed: c.method == "registration" and c.heading_flips.enabled and timed,
              ("heading_flips.enabled", False),
              "registrations whose heading disagrees with the travel (flips, quarter turns) turned back"),
    TrackPass("coast", coast_ends,
              lambda c, timed: c.method == "registration" and c.chain_neighbours > 0 and c.coast_frames > 0 and timed,
              ("coast_frames", 0),
              "one unregistered frame past either end takes the constant-velocity prediction when its points fit"),
)


def build_track(b: TrackBuilder, config: TrajectoryConfig) -> TrackBuilder:
    """Run every pass of :data:`TRACK_PASSES` that ``config`` switches on, in order."""
    for p in TRACK_PASSES:
        if p.runs_when(config, b.times is not None):
            p.run(b, config)
    return b
