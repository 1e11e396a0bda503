"""Instances that barely move become static background (supplementary, "Trajectory smoothing":
total displacement below 1 m)."""

from __future__ import annotations

from dataclasses import dataclass, replace

from idsplat_ns.instances.tracks import InstanceTracks


@dataclass(frozen=True)
class StaticConversionConfig:
    """When an instance counts as static."""

    min_displacement: float = 1.0
    """Metres: instances whose largest distance between two valid positions is below this are static."""
    min_valid_frames: int = 2
    """Instances with fewer valid poses than this cannot show motion and are made static too."""


def convert_static_instances(tracks: InstanceTracks, config: StaticConversionConfig = StaticConversionConfig()) -> InstanceTracks:
    """A copy of ``tracks`` with barely moving instances moved to ``static_instances``."""
    dynamic, static = [], list(tracks.static_instances)
    for inst in tracks.instances:
        moving = inst.num_valid >= config.min_valid_frames and inst.displacement() >= config.min_displacement
        (dynamic if moving else static).append(inst)
    return replace(tracks, instances=dynamic, static_instances=static,
                   metadata={**tracks.metadata, "static_min_displacement": config.min_displacement})
