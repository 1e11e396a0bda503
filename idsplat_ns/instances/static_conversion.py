"""Instances that do not move become static background.

Two tests, either of which makes an instance static:

* **Displacement** (the paper, supplementary "Trajectory smoothing"): the largest distance between
  two registered positions is below 1 m.
* **World overlap** (ours): without any motion, the instance's lidar points of one frame lie on
  the surfaces seen in its other frames. Registration of a parked car that the ego passes at close
  range can slide by metres along the car's flat side when the visible side changes (measured on
  the synthetic street: 1.2-3.6 m of false displacement on three parked cars, docs/instances.md),
  which the displacement test alone takes for motion. The overlap test needs no registration:
  for each observed frame, the fraction of its world points within ``overlap_distance`` of the
  points of the instance's other frames; a parked vehicle scores near 1 in almost every frame,
  a moving one near 0 (it scores high only while it is stopped). One motion fools point distances:
  a flat side sliding along itself (a bus driving past) still lies on its own plane. So the test
  also asks that the union of the agreeing frames' points be no longer, along its main horizontal axis,
  than the longest single view plus ``min_displacement``: a parked object's views share one
  extent, a moving one's union grows by the distance travelled.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional, Sequence

import numpy as np
from scipy.spatial import cKDTree

from idsplat_ns.instances.lifting import InstanceObservation, LiftedInstances
from idsplat_ns.instances.tracks import InstanceTrack, InstanceTracks
from idsplat_ns.ranges import UNIT, bounded


@dataclass(frozen=True)
class StaticConversionConfig:
    """When an instance counts as static."""

    min_displacement: float = 1.0
    """Metres: instances whose largest distance between two valid positions is below this are static."""
    min_valid_frames: int = 2
    """Instances with fewer valid poses than this cannot show motion and are made static too."""
    use_world_overlap: bool = True
    """Also make an instance static when its points agree across frames with no motion (see the
    module docstring); False keeps only the paper's displacement rule."""
    overlap_distance: float = 0.10
    """Metres: a point agrees with the other frames when one of their points is this close
    (the registration's inlier distance)."""
    overlap_point_fraction: float = bounded(0.5, UNIT)
    """A frame agrees with no motion when at least this fraction of its points agree (the
    registration's fitness threshold)."""
    overlap_frame_fraction: float = bounded(0.8, UNIT)
    """An instance is stationary when at least this fraction of its observed frames agree; a car
    that parks for part of the sequence and drives for the rest stays dynamic."""
    overlap_min_points: int = 10
    """Frames with fewer points than this are not scored."""
    # The extent check reuses ``min_displacement`` (see the module docstring).


def static_threshold(option: Optional[float], tracks: Optional[InstanceTracks]) -> float:
    """Metres below which an instance is static: the option, else the preprocessing's (so the
    model never undoes a smaller threshold the user gave there), else the paper's 1 m."""
    if option is not None:
        return float(option)
    if tracks is not None and "static_min_displacement" in tracks.metadata:
        return float(tracks.metadata["static_min_displacement"])
    return StaticConversionConfig().min_displacement


def world_overlap_fractions(
    observations: Sequence[InstanceObservation], distance: float, min_points: int = 10
) -> np.ndarray:  # -> [K] one fraction per scored frame
    """For each observation with at least ``min_points`` points, the fraction of its world
    points within ``distance`` of a point of the instance's other observations."""
    clouds = [o for o in observations if len(o.points)]
    near = near_other_clouds([o.points for o in clouds], distance)
    return np.asarray([float(np.mean(n)) for o, n in zip(clouds, near)
                       if len(o.points) >= min_points and len(clouds) > 1], dtype=np.float64)


def near_other_clouds(clouds: list[np.ndarray], distance: float) -> list[np.ndarray]:
    """Per cloud [N_i, 3], [N_i] bool: whether each point has a point of another cloud within
    ``distance``. The clouds are halved, each half's points looked up in a tree of the other
    half's, then each half alone, recursively: log2(K) levels of trees over all the points, where
    a tree of the others per cloud would hold K - 1 clouds K times (200 frames of a car: 21 s)."""
    near = [np.zeros(len(c), bool) for c in clouds]

    def split(index: list[int]) -> None:
        if len(index) < 2:
            return
        half = len(index) // 2
        for ones, others in ((index[:half], index[half:]), (index[half:], index[:half])):
            tree = cKDTree(np.concatenate([clouds[k] for k in others]))
            for k in ones:
                open_ = ~near[k]
                dist, _ = tree.query(clouds[k][open_], k=1, distance_upper_bound=distance)
                near[k][open_] = np.isfinite(dist)
        split(index[:half])
        split(index[half:])

    split(list(range(len(clouds))))
    return near


def extent_growth(observations: Sequence[InstanceObservation], trim: float = 0.01) -> float:
    """Metres by which the union of the observations is longer than the longest single view,
    along the union's main horizontal axis (trimmed extents: ``trim`` of the points ignored at
    each end)."""
    clouds = [o.points[:, :2] for o in observations if len(o.points)]
    if len(clouds) < 2:
        return 0.0
    union = np.concatenate(clouds)
    centred = union - union.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    axis = vt[0]

    def extent(xy: np.ndarray) -> float:  # xy: [N, 2]
        lo, hi = np.quantile(xy @ axis, [trim, 1.0 - trim])
        return float(hi - lo)

    return extent(union) - max(extent(c) for c in clouds)


def is_stationary(observations: Sequence[InstanceObservation], config: StaticConversionConfig) -> bool:
    """The world-overlap test of the module docstring."""
    scored = [o for o in observations if len(o.points) >= config.overlap_min_points]
    fractions = world_overlap_fractions(scored, config.overlap_distance, config.overlap_min_points)
    if len(fractions) < 2 or len(fractions) != len(scored):
        return False
    agree = fractions >= config.overlap_point_fraction
    if np.mean(agree) < config.overlap_frame_fraction:
        return False
    # Only the agreeing views: one mis-painted frame (points of another object) must not stretch it.
    return extent_growth([o for o, a in zip(scored, agree) if a]) < config.min_displacement


def convert_static_instances(
    tracks: InstanceTracks,
    config: StaticConversionConfig = StaticConversionConfig(),
    lifted: Optional[LiftedInstances] = None,
) -> InstanceTracks:
    """A copy of ``tracks`` with non-moving instances moved to ``static_instances``.

    ``lifted`` (the observations the tracks were registered from) enables the world-overlap test;
    without it only the displacement rule applies.
    """
    dynamic, static = [], list(tracks.static_instances)
    stationary_ids = []
    for inst in tracks.instances:
        moving = inst.num_valid >= config.min_valid_frames and inst.displacement() >= config.min_displacement
        if moving and config.use_world_overlap and lifted is not None:
            obs = lifted.observations.get(inst.instance_id, [])
            if is_stationary(obs, config):
                moving = False
                stationary_ids.append(inst.instance_id)
        (dynamic if moving else static).append(inst)
    # Extend, not replace: the model runs the displacement rule again on tracks already converted.
    overlap = list(tracks.metadata.get("static_by_world_overlap", [])) + stationary_ids
    meta = {**tracks.metadata, "static_min_displacement": config.min_displacement, "static_by_world_overlap": overlap}
    return replace(tracks, instances=dynamic, static_instances=static, metadata=meta)


def static_reason(inst: InstanceTrack, config: StaticConversionConfig, metadata: Optional[dict] = None) -> str:
    """Why ``inst`` is static under ``config`` (``metadata``: its tracks', for the world-overlap test)."""
    if inst.instance_id in (metadata or {}).get("static_by_world_overlap", []):
        return "its points agree across frames (world overlap): it does not move"
    if inst.num_valid < config.min_valid_frames:
        return f"seen in {inst.num_valid} frame(s): no motion to model"
    moved = inst.displacement()
    if moved < config.min_displacement:
        return f"moved {moved:.2f} m, under {config.min_displacement:g} m"
    return "static in its tracks"
