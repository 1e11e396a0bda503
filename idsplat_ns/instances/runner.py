"""The preprocessing runner: masks -> point painting -> features -> registration -> static
conversion -> smoothing, each stage cached atomically by its inputs and settings, with a timing
table by stage like the paper's Table 13. Used by ``idsplat-preprocess`` (and, with issue 7's
instance model, by the datamanager).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from idsplat_ns.data.geometry import interpolate_poses
from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.amodal_centre import AmodalCentreConfig, box_heading, complete_centres, travel_direction
from idsplat_ns.instances.cache import atomic_path, hash_json, remove_stale_temporaries, scene_fingerprint
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.ground import GroundSurface
from idsplat_ns.instances.options import cli_option
from idsplat_ns.instances.smoothing import SmoothingConfig, smooth_trajectory
from idsplat_ns.instances.smoothing.observability import translation_covariances
from idsplat_ns.instances.smoothing.smoother import SmoothedTrajectory
from idsplat_ns.instances.features.config import FeatureConfig, make_feature_extractor, resolve_feature_kind
from idsplat_ns.instances.masks.lidar_motion import LidarMotionMaskSource
from idsplat_ns.instances.lidar_motion_lifting import lift_track_points
from idsplat_ns.instances.lifting import LiftedInstances, LiftingConfig, lift_instances
from idsplat_ns.instances.masks.base import InstanceMaskSet
from idsplat_ns.instances.masks.config import MaskConfig, make_mask_source, resolve_mask_kind
from idsplat_ns.instances.masks.perturb import MaskNoiseConfig, perturb_mask_set
from idsplat_ns.instances.masks.precomputed import load_mask_set
from idsplat_ns.instances.static_conversion import StaticConversionConfig, convert_static_instances
from idsplat_ns.instances.trajectory_estimation import TrajectoryConfig, estimate_trajectories
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks

# Bumped when what the registration stage stores changes (2: per-point origin frames; 3: ray times).
TRACKS_FORMAT = 3
# Bumped when what the lifting stage stores changes (2: per-point ray times).
LIFTING_FORMAT = 2
# Bumped when the registration gives other results for the same settings, so that a cache made by
# older code is not reused (2: ICP linearised about the pairs' centroid; 3: heading turns about the
# amodal centre, parked instances not turned; 5: segments linked along the box's axis, not the
# origin's mean travel direction; 6: hypotheses that tilt the vehicle are not considered; 7: the
# fewest frames of either part dropped to link a segment; 8: normals from open3d, equal to rounding,
# which moves some borderline fitness decisions; 9: beside a single registered frame the chain
# predicts with the observations' centroid velocity, its gate grows with the extrapolation, and
# the reference frame may be a motion outlier too).
REGISTRATION_VERSION = 9
# The same for the smoothing stage (2: translations not measured by a frame's surfaces; 3: tilt and
# vertical motion sigmas; 4: one-sided faces left to the motion; 5: heading prior and vertical cap;
# 6: turning curvature; 7: lidar ground under the vehicles, sparse views left to the motion).
SMOOTHING_VERSION = 7


@dataclass(frozen=True)
class PreprocessConfig:
    """Every setting of instance preprocessing (defaults: the paper's)."""

    masks: MaskConfig = field(default_factory=MaskConfig)
    """Mask source."""
    mask_noise: Optional[MaskNoiseConfig] = None
    """Corrupt the masks before lifting (robustness tests only; None in normal use)."""
    lifting: LiftingConfig = field(default_factory=LiftingConfig)
    """Mask-to-lidar lifting."""
    features: FeatureConfig = field(default_factory=FeatureConfig)
    """Point features for correspondences."""
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    """Registration (or the centroid ablation)."""
    static: StaticConversionConfig = field(default_factory=StaticConversionConfig)
    """Static conversion of barely moving instances."""
    smoothing: Optional[SmoothingConfig] = field(default_factory=SmoothingConfig)
    """Coordinated-turn smoothing settings (paper defaults); None skips the stage."""
    amodal: AmodalCentreConfig = field(default_factory=AmodalCentreConfig)
    """Canonical origins at the middle of the whole vehicle (ours; see instances/amodal_centre.py)."""


@dataclass
class StageTiming:
    """Wall time of one stage."""

    name: str
    seconds: float
    cached: bool
    note: str = ""


@dataclass
class PreprocessResult:
    """What a run produced."""

    tracks: InstanceTracks
    timings: list[StageTiming]
    mask_source: str
    feature_extractor: Optional[str]

    @property
    def total_seconds(self) -> float:
        return sum(t.seconds for t in self.timings)

    def timing_table(self) -> str:
        """A text table like the paper's Table 13 (time per stage and share of the total)."""
        total = max(self.total_seconds, 1e-9)
        lines = [f"{'stage':<20}{'time [s]':>10}{'share':>9}  source", "-" * 56]
        for t in self.timings:
            src = "cache" if t.cached else ("skipped" if t.note.startswith("skipped") else "computed")
            lines.append(f"{t.name:<20}{t.seconds:>10.2f}{100 * t.seconds / total:>8.1f}%  {src}{(' - ' + t.note) if t.note else ''}")
        lines.append("-" * 56)
        lines.append(f"{'total':<20}{self.total_seconds:>10.2f}")
        return "\n".join(lines)


def _cached_file(path: Path, compute: Callable[[], object], save: Callable[[object, Path], None],
                 load: Callable[[Path], object]) -> tuple[object, bool]:
    """Load ``path`` if present, else compute, save atomically and return (result, was_cached)."""
    if path.is_file():
        return load(path), True
    result = compute()
    with atomic_path(path) as tmp:
        save(result, tmp)
    return result, False


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


def ground_surface(scene: Scene, config: SmoothingConfig) -> Optional[GroundSurface]:
    """The lidar ground the smoother keeps vehicles on, or None where ``config`` does not ask for
    it or the scene has no lidar."""
    if config.ground_height_walk_rate is None or not scene.has_lidar:
        return None
    return GroundSurface.from_sweeps(scene.lidar, config.ground)


def smooth_instance(inst: InstanceTrack, times: np.ndarray, config: SmoothingConfig,
                    ground: Optional[GroundSurface] = None) -> SmoothedTrajectory:
    """Smooth one instance's registrations placed at ``times`` [F] (seconds), with the translation
    covariances of its views, the heading prior of its box axis and the ``ground`` under it, as
    ``config`` asks."""
    heading = instance_heading(inst, config.heading_prior_min_points) if config.heading_prior_sigma is not None else None
    return smooth_trajectory(times, inst.poses, inst.valid, config,
                             measurement_covariances(inst, len(times), config, heading is not None), heading,
                             None if ground is None else ground.heights_at)


def smooth_tracks(tracks: InstanceTracks, config: SmoothingConfig, ground: Optional[GroundSurface] = None) -> InstanceTracks:
    """Replace each dynamic instance's poses by smoothed ones at the frame times (valid within the
    measured span).

    Each registration is placed at its points' mean ray time (``config.measurement_times``), not
    the frame's: the rays that hit a car are fired up to half a sweep away from the frame time,
    and a car at 12 m/s is 0.3 m elsewhere then (measured on the synthetic street). The poses are
    then read at the frame times from the CT model, and each point is re-posed with the pose at
    its own ray time (``config.repose_points``), which also undoes the car's motion during the
    sweep, as the oracle does with the annotated boxes.
    """
    out = []
    times = np.asarray(tracks.frame_times, np.float64)
    for inst in tracks.instances:
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
        out.append(replace(inst, poses=frame_poses, valid=valid, measured_valid=inst.valid))
    return replace(tracks, instances=out, metadata={**tracks.metadata, "smoothed": True})


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


def run_preprocessing(
    scene: Scene,
    config: PreprocessConfig,
    cache_dir: Path,
    output_path: Optional[Path] = None,
    progress: bool = True,
    verbose: bool = True,
) -> PreprocessResult:
    """Run every stage for ``scene`` with caches under ``cache_dir``; write the final tracks to
    ``output_path`` (atomically) when given."""
    if not scene.has_lidar:
        raise IDSplatError(f"scene {scene.name} has no lidar; instance decomposition lifts masks to lidar points")
    cache_dir = Path(cache_dir)
    cache_dir.mkdir(parents=True, exist_ok=True)
    stale = remove_stale_temporaries(cache_dir)
    if stale and verbose:
        print(f"note: removed {stale} unfinished cache entries left by an interrupted run")
    timings: list[StageTiming] = []

    # 1. Mask generation.
    t0 = time.perf_counter()
    scene_key = scene_fingerprint(scene)
    mask_kind = resolve_mask_kind(config.masks)
    if config.masks.kind == "auto" and mask_kind == "lidar-motion" and verbose:
        print("note: no Grounded-SAM-2 files and no mask folder given: instances come from lidar motion "
              f"({cli_option('masks.kind')} lidar-motion; docs/instances.md)")
    source = make_mask_source(mask_kind, config.masks)
    mask_key = hash_json({"scene": scene_key, "source": source.cache_key()})
    cached = True
    if source.writes_output:
        mask_dir = cache_dir / f"masks-{mask_key}"
        if mask_dir.is_dir():
            masks = load_mask_set(mask_dir, source=source.name)
        else:
            cached = False
            with atomic_path(mask_dir) as tmp:
                source.generate(scene, tmp, progress)
            masks = load_mask_set(mask_dir, source=source.name)
    else:  # read in place from the user's folder: nothing cached
        cached = False
        masks = source.generate(scene, cache_dir, progress)
    if config.mask_noise is not None:
        mask_key = hash_json({"masks": mask_key, "noise": asdict(config.mask_noise)})
        noisy_dir = cache_dir / f"masks-noisy-{mask_key}"
        cached = noisy_dir.is_dir()  # the noisy copy is what the later stages read
        if not cached:
            with atomic_path(noisy_dir) as tmp:
                perturb_mask_set(masks, scene, tmp, config.mask_noise)
        masks = InstanceMaskSet(noisy_dir, load_mask_set(noisy_dir).labels, f"{masks.source}+noise")
    timings.append(StageTiming("mask generation", time.perf_counter() - t0, cached, masks.source))

    # 2. Point painting (lifting masks to lidar), or for lidar motion its tracks' own points (not
    # its masks' hulls painted back), unless its masks were perturbed (then the masks are what is
    # measured).
    t0 = time.perf_counter()
    own_points = masks.source == LidarMotionMaskSource.name and config.masks.lidar_motion.lift_own_points
    lift_key = hash_json({"masks": mask_key, "lifting": asdict(config.lifting), "format": LIFTING_FORMAT,
                          "own_points": own_points})
    lifted, cached = _cached_file(
        cache_dir / f"lifting-{lift_key}.npz",
        lambda: (lift_track_points(scene, masks.root, masks.labels, config.lifting, progress) if own_points
                 else lift_instances(scene, masks, config.lifting, progress)),
        lambda r, p: r.save(p), LiftedInstances.load)
    n_obs = sum(len(v) for v in lifted.observations.values())
    how = "the tracks' own points, " if own_points else ""
    timings.append(StageTiming("point painting", time.perf_counter() - t0, cached,
                               f"{how}{len(lifted.observations)} instances, {n_obs} observations"))

    # 3. Point features (not needed by the centroid ablation).
    features: Optional[PointFeatures] = None
    feat_key = hash_json({"lifting": lift_key, "features": None})
    extractor_name = None
    if config.trajectory.method == "registration":
        t0 = time.perf_counter()
        extractor_name = resolve_feature_kind(config.features, scene)
        extractor = make_feature_extractor(extractor_name, config.features)
        feat_key = hash_json({"lifting": lift_key, "features": extractor.cache_key()})
        features, cached = _cached_file(
            cache_dir / f"features-{feat_key}.npz",
            lambda: extractor.extract(scene, lifted, progress),
            lambda r, p: r.save(p), PointFeatures.load)
        timings.append(StageTiming("features", time.perf_counter() - t0, cached, extractor_name))

    # 4. Registration.
    t0 = time.perf_counter()
    reg_key = hash_json({"features": feat_key, "trajectory": asdict(config.trajectory), "format": TRACKS_FORMAT,
                         "version": REGISTRATION_VERSION})
    tracks, cached = _cached_file(
        cache_dir / f"registration-{reg_key}.npz",
        lambda: estimate_trajectories(scene, lifted, features, config.trajectory, progress),
        lambda r, p: r.save(p), InstanceTracks.load)
    tracks.metadata.update({"mask_source": masks.source})
    timings.append(StageTiming("registration", time.perf_counter() - t0, cached, config.trajectory.method))

    # 5. Static conversion.
    t0 = time.perf_counter()
    tracks = convert_static_instances(tracks, config.static, lifted)
    timings.append(StageTiming("static conversion", time.perf_counter() - t0, False,
                               f"{len(tracks.instances)} dynamic, {len(tracks.static_instances)} static"))

    # 6. Coordinated-turn smoothing (Sec. 3.4).
    t0 = time.perf_counter()
    if config.smoothing is None:
        timings.append(StageTiming("smoothing", 0.0, False, "skipped (disabled)"))
    else:
        # Keyed on which instances stayed dynamic too, not only on the settings that decided it.
        dynamic_ids = sorted(int(i.instance_id) for i in tracks.instances)
        smooth_key = hash_json({"registration": reg_key, "static": asdict(config.static), "dynamic": dynamic_ids,
                                "smoothing": asdict(config.smoothing), "version": SMOOTHING_VERSION})
        smoothing = config.smoothing
        tracks, cached = _cached_file(
            cache_dir / f"smoothing-{smooth_key}.npz",
            lambda: smooth_tracks(tracks, smoothing, ground_surface(scene, smoothing)),
            lambda r, p: r.save(p), InstanceTracks.load)
        timings.append(StageTiming("smoothing", time.perf_counter() - t0, cached))

    # 7. Amodal canonical origins (cheap, not cached).
    t0 = time.perf_counter()
    if config.amodal.enabled:
        tracks = complete_centres(tracks, scene.lidar_positions(), config.amodal)
        timings.append(StageTiming("amodal centres", time.perf_counter() - t0, False,
                                   f"{len(tracks.metadata.get('amodal_centre_shift', {}))} moved"))
    else:
        timings.append(StageTiming("amodal centres", 0.0, False, "skipped (disabled)"))

    tracks.metadata.update({"mask_source": masks.source, "features": extractor_name,
                            "trajectory_method": config.trajectory.method})
    if output_path is not None:
        with atomic_path(Path(output_path)) as tmp:
            tracks.save(tmp)
    result = PreprocessResult(tracks, timings, masks.source, extractor_name)
    if verbose:
        print(result.timing_table())
    return result
