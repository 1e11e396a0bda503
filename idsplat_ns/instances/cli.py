"""``idsplat-preprocess``: instance decomposition of one sequence (masks, lifting, features,
registration, static conversion, smoothing) with stage caches and a timing table.

Example::

    idsplat-preprocess --data /data/pandaset/001 --masks.kind precomputed \\
        --masks.precomputed.mask-dir /data/masks/001 --features.kind daisy
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from idsplat_ns.errors import run_cli
from idsplat_ns.instances.features.config import FeatureConfig
from idsplat_ns.instances.lifting import LiftingConfig
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.runner import PreprocessConfig, run_preprocessing
from idsplat_ns.instances.smoothing import SmoothingConfig
from idsplat_ns.instances.static_conversion import StaticConversionConfig
from idsplat_ns.instances.trajectory_estimation import TrajectoryConfig


@dataclass
class PreprocessArgs:
    """Instance decomposition of one sequence (IDSplat, Sec. 3.2-3.4)."""

    data: Path
    """A PandaSet sequence folder (the built-in synthetic street writes the same layout) or a Waymo
    v1 ``segment-*.tfrecord`` file (or a v2 root with ``--context-name``)."""
    context_name: Optional[str] = None
    """Waymo v2 only: the segment context name inside the v2 root given as data."""
    output: Optional[Path] = None
    """Where the instance tracks go (default ``<data>/idsplat_instances/instance_tracks.npz``)."""
    cache_dir: Optional[Path] = None
    """Stage caches (default: ``cache/`` next to the output)."""
    start: int = 0
    """First frame index kept."""
    end: Optional[int] = None
    """One past the last frame index kept (default: all)."""
    cameras: Optional[tuple[str, ...]] = None
    """Camera names to use (default: all)."""
    masks: MaskConfig = field(default_factory=MaskConfig)
    """Mask source."""
    lifting: LiftingConfig = field(default_factory=LiftingConfig)
    """Lifting of masks to lidar."""
    features: FeatureConfig = field(default_factory=FeatureConfig)
    """Point features for correspondences."""
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    """Registration settings."""
    static: StaticConversionConfig = field(default_factory=StaticConversionConfig)
    """Static conversion."""
    smoothing: bool = True
    """Smooth trajectories with the coordinated-turn model (paper settings)."""
    progress: bool = True
    """Show progress bars."""


def preprocess(args: PreprocessArgs):
    """Load the sequence and run every stage; returns the runner's result."""
    data = Path(args.data)
    if data.is_file() or args.context_name is not None:
        from idsplat_ns.data.waymo import load_segment

        scene = load_segment(data, cameras=list(args.cameras) if args.cameras else None, start=args.start,
                             end=args.end, context_name=args.context_name)
        default_root = data.parent / f"{scene.name}_idsplat_instances"
    else:
        from idsplat_ns.data.pandaset import load_sequence

        scene = load_sequence(data, cameras=args.cameras, start=args.start, end=args.end)
        default_root = data / "idsplat_instances"
    output = args.output or default_root / "instance_tracks.npz"
    cache_dir = args.cache_dir or Path(output).parent / "cache"
    config = PreprocessConfig(masks=args.masks, lifting=args.lifting, features=args.features,
                              trajectory=args.trajectory, static=args.static,
                              smoothing=SmoothingConfig() if args.smoothing else None)
    print(scene.summary())
    result = run_preprocessing(scene, config, cache_dir, output, progress=args.progress)
    print(f"wrote {output}: {len(result.tracks.instances)} dynamic instances, "
          f"{len(result.tracks.static_instances)} made static (masks: {result.mask_source}, "
          f"features: {result.feature_extractor})")
    return result


def main(argv: Optional[list[str]] = None) -> None:
    """Console entry point."""
    import tyro

    args = tyro.cli(PreprocessArgs, args=sys.argv[1:] if argv is None else argv)
    run_cli(lambda: preprocess(args))


if __name__ == "__main__":
    main()
