"""The preprocessing runner: masks -> point painting -> features -> registration -> static
conversion -> smoothing, each stage cached atomically by its inputs and settings, with a timing
table by stage like the paper's Table 13. Used by ``idsplat-preprocess`` (and, with issue 7's
instance model, by the datamanager).
"""

from __future__ import annotations

import functools
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Optional

from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.amodal_centre import AmodalCentreConfig, complete_centres
from idsplat_ns.instances.contained_parts import absorb_contained_parts
from idsplat_ns.instances.cache import atomic_path, hash_json, remove_stale_temporaries, scene_fingerprint
from idsplat_ns.instances.features.base import PointFeatures
from idsplat_ns.instances.ground import GroundConfig, GroundSurface
from idsplat_ns.instances.options import cli_option
from idsplat_ns.instances.smoothing import SmoothingConfig
from idsplat_ns.instances.smoothing.instance_tracks import smooth_tracks, uses_ground
from idsplat_ns.instances.features.config import FeatureConfig, make_feature_extractor, resolve_feature_kind
from idsplat_ns.instances.masks.lidar_motion import LidarMotionMaskSource
from idsplat_ns.instances.lidar_motion_lifting import lift_track_points, load_lidar_views
from idsplat_ns.instances.lifting import LiftedInstances, LiftingConfig, lift_instances
from idsplat_ns.instances.masks.base import InstanceMaskSet
from idsplat_ns.instances.masks.config import MaskConfig, make_mask_source, resolve_mask_kind
from idsplat_ns.instances.masks.perturb import MaskNoiseConfig, perturb_mask_set
from idsplat_ns.instances.masks.precomputed import load_mask_set
from idsplat_ns.instances.static_conversion import StaticConversionConfig, convert_static_instances
from idsplat_ns.instances.trajectory_config import TrajectoryConfig
from idsplat_ns.instances.trajectory_estimation import estimate_trajectories
from idsplat_ns.instances.tracks import InstanceTracks

# Bumped when what the registration stage stores changes (2: per-point origin frames; 3: ray times).
TRACKS_FORMAT = 3
# Bumped when what the lifting stage stores changes (2: per-point ray times; 3: the share of a
# lidar-motion cluster the cameras see; 4: every lidar-motion cluster whole, seen or not; 5: not
# those again, registration reads them from the mask folder).
LIFTING_FORMAT = 5
# Bumped when the registration gives other results for the same settings, so that a cache made by
# older code is not reused (2: ICP linearised about the pairs' centroid; 3: heading turns about the
# amodal centre, parked instances not turned; 5: segments linked along the box's axis, not the
# origin's mean travel direction; 6: hypotheses that tilt the vehicle are not considered; 7: the
# fewest frames of either part dropped to link a segment; 8: normals from open3d, equal to rounding,
# which moves some borderline fitness decisions; 9: beside a single registered frame the chain
# predicts with the observations' centroid velocity, its gate grows with the extrapolation, and
# the reference frame may be a motion outlier too; 11: long vehicles' views the cameras cut are left
# to the chain first; 12: tracks carried through the frames only the lidar saw; 13: vehicles only).
REGISTRATION_VERSION = 13
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
    workers: int = 0
    """Processes that register and smooth instances side by side: 0, one per CPU core once the
    scene has a few hundred instance-frames (instances/process_pool.py); 1, all in this process.
    The tracks do not depend on it (nor do the caches)."""

    def __post_init__(self) -> None:
        if self.workers < 0:  # before any stage runs
            raise IDSplatError(f"preprocess workers={self.workers}: choose 0 (one per core) or more ({cli_option('workers')})")


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
    # Carrying out of the cameras' view reads the lidar-motion clusters whole from the mask folder
    # (in the key through the lifting's): other mask sources know no points the cameras missed.
    carry = own_points and config.trajectory.out_of_view_frames > 0
    tracks, cached = _cached_file(
        cache_dir / f"registration-{reg_key}.npz",
        lambda: estimate_trajectories(
            scene, lifted, features, config.trajectory, progress, config.workers,
            load_lidar_views(scene, masks.root, lifted.observations, config.lifting.min_points) if carry else None),
        lambda r, p: r.save(p), InstanceTracks.load)
    tracks.metadata.update({"mask_source": masks.source})
    timings.append(StageTiming("registration", time.perf_counter() - t0, cached, config.trajectory.method))

    # 5. Static conversion.
    t0 = time.perf_counter()
    tracks = convert_static_instances(tracks, config.static, lifted)
    timings.append(StageTiming("static conversion", time.perf_counter() - t0, False,
                               f"{len(tracks.instances)} dynamic, {len(tracks.static_instances)} static"))

    # The lidar ground (lowest points per cell of every sweep), built at most once: the smoother
    # keeps vehicles on it and the amodal centres stand on it.
    ground_config = config.smoothing.ground if config.smoothing is not None else GroundConfig()
    lidar_ground = functools.cache(lambda: GroundSurface.from_sweeps(scene.lidar, ground_config))

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
            lambda: smooth_tracks(tracks, smoothing, lidar_ground() if uses_ground(scene, smoothing) else None,
                                  config.workers, progress),
            lambda r, p: r.save(p), InstanceTracks.load)
        timings.append(StageTiming("smoothing", time.perf_counter() - t0, cached))

    # 7. Amodal canonical origins (cheap, not cached).
    t0 = time.perf_counter()
    if config.amodal.enabled:
        amodal = config.amodal
        on_ground = (amodal.ground_contact or amodal.tall_roof_height is not None) and scene.has_lidar
        tracks = complete_centres(tracks, scene.lidar_positions(), amodal, lidar_ground().heights_at if on_ground else None)
        tracks = absorb_contained_parts(tracks, amodal.parts)
        timings.append(StageTiming("amodal centres", time.perf_counter() - t0, False,
                                   f"{len(tracks.metadata.get('amodal_centre_shift', {}))} moved, "
                                   f"{len(tracks.metadata.get('folded_parts', {}))} parts folded into long vehicles"))
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
