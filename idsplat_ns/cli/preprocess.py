"""``idsplat-preprocess``: the instance decomposition of one sequence alone (masks, lifting,
features, registration, static conversion, smoothing), with a stage timing table.

It reads the data as ``ns-train`` does (the same format recognition, protocol and train/eval
split) and writes the same stage caches (``$IDSPLAT_CACHE/instances/<sequence>``), so a following
``ns-train`` with the same data and settings starts from them. ``--export`` writes the tracks as
JSON in the data's own frame and clock (docs/instances.md); ``ns-train ...
--pipeline.datamanager.import-tracks FILE`` trains from such a file.

Example::

    idsplat-preprocess --data /data/pandaset/001 --export tracks.json
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional

from idsplat_ns.atomic import check_writable
from idsplat_ns.data.scene import note_empty_sweeps
from idsplat_ns.data.split import split_frames
from idsplat_ns.errors import run_cli
from idsplat_ns.instances.modes import instance_tracks_for_mode
from idsplat_ns.instances.runner import PreprocessConfig
from idsplat_ns.instances.tracks_json import write_tracks_json
from idsplat_ns.nerfstudio.builtin_scene import instance_cache_dir
from idsplat_ns.nerfstudio.dataparser import AutoDataParserConfig


@dataclass
class PreprocessArgs:
    """Instance decomposition of one sequence (IDSplat, Sec. 3.2-3.4), cached as ns-train caches it."""

    data: Optional[Path] = None
    """As ns-train's --data: a PandaSet sequence folder, a Waymo v1 .tfrecord (or a folder of them with
    --segment), a v2 root (with --context-name); none: the built-in street."""
    segment: Optional[str] = None
    """Waymo v1 folder of segments: which one."""
    context_name: Optional[str] = None
    """Waymo v2 root: which context."""
    protocol: Optional[str] = None
    """One of the paper's protocols (frames, cameras and split), as in ns-train."""
    cameras: Optional[tuple[str, ...]] = None
    """Camera names to use (default: all)."""
    start_frame: int = 0
    """First frame index kept."""
    end_frame: Optional[int] = None
    """One past the last frame index kept (default: all)."""
    train_fraction: Optional[float] = None
    """Training share of the frames (default: the format's, as in ns-train); only training frames are used."""
    eval_every: Optional[int] = None
    """Hold out every k-th frame (overrides train_fraction)."""
    lidars: Optional[tuple[str, ...]] = None
    """Waymo: lidars to load (TOP, FRONT, SIDE_LEFT, SIDE_RIGHT, REAR); default all five, as in ns-train."""
    second_return: bool = True
    """Waymo: also keep second returns, as in ns-train."""
    lidar_sensors: tuple[int, ...] = (0,)
    """PandaSet: lidars to use (0 the Pandar64, 1 the front PandarGT), as in ns-train."""
    builtin_preset: str = "small"
    """Without --data: the built-in street's preset."""
    builtin_seed: int = 0
    """Without --data: the built-in street's seed."""
    instance_mode: Literal["self-supervised", "oracle"] = "self-supervised"
    """``self-supervised`` (the method) or ``oracle`` (the annotated tracks, for comparison)."""
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    """Stage settings: the same as ns-train's --pipeline.datamanager.preprocess."""
    export: Optional[Path] = None
    """Also write the instance tracks as JSON here (data's own world frame and timestamps)."""


def preprocess(args: PreprocessArgs):
    """Load the sequence as ns-train does, run (or reuse) every stage, optionally export; returns the tracks."""
    if args.export is not None:  # before the work, not after it
        check_writable(args.export, "--export", folder=False)
    config = AutoDataParserConfig(
        data=args.data, segment=args.segment, context_name=args.context_name, protocol=args.protocol,
        cameras=args.cameras, start_frame=args.start_frame, end_frame=args.end_frame,
        train_fraction=args.train_fraction, eval_every=args.eval_every, lidars=args.lidars,
        second_return=args.second_return, lidar_sensors=args.lidar_sensors,
        builtin_preset=args.builtin_preset, builtin_seed=args.builtin_seed,
    ).resolved()
    scene = config.load_scene()
    print(scene.summary())
    note_empty_sweeps(scene)
    train_idx, _ = split_frames(scene.num_frames, config.train_fraction, config.eval_every)
    train_frames = set(scene.frame_indices[train_idx].tolist())
    cache_dir = instance_cache_dir(scene.name)
    tracks = instance_tracks_for_mode(scene, args.instance_mode, train_frames, args.preprocess, cache_dir)
    if tracks is None:
        print("no instances (static mode)")
        return None
    print(f"{len(tracks.instances)} dynamic instances, {len(tracks.static_instances)} made static; "
          f"stage caches in {cache_dir} (ns-train with the same data and settings reuses them)")
    if args.export is not None:
        write_tracks_json(args.export, tracks, scene.subset(train_frames))
        print(f"wrote {args.export}")
    return tracks


def parse_args(argv: list[str]) -> PreprocessArgs:
    """The command line's settings; tyro exits with its message on an unknown option."""
    import tyro

    # True/false options take a value (--second-return False), as in ns-train, so that its
    # --pipeline.datamanager.preprocess.* options carry over with only the prefix changed.
    return tyro.cli(tyro.conf.FlagConversionOff[PreprocessArgs], args=argv)


def main(argv: Optional[list[str]] = None) -> None:
    """Console entry point."""
    run_cli(lambda: preprocess(parse_args(sys.argv[1:] if argv is None else argv)))  # settings' checks end in one line


if __name__ == "__main__":
    main()
