"""How the instance tracks depend on the 2D masks: the same built-in streets preprocessed with
masks from (a) the generator's ground truth, (b) that ground truth degraded (missed detections,
eroded or dilated edges, false positives, identity swaps; ``instances/masks/perturb.py``) and
(c) the lidar-motion source, the default when there are no model files. Per source: MOTA@2m,
MOTP@2m, precision, recall and identity switches of the moving vehicles (the observed protocol, pooled over the
streets) and the preprocessing time.

    .venv/bin/python -m bench.bench_mask_sources --preset small --seeds 100 101 102 103 104 --work WORK
    .venv/bin/python -m bench.bench_mask_sources --sources "lidar motion" "lidar motion, points painted back through its masks"

The preprocessing is ``ns-train``'s (``instance_tracks_for_mode``, self-supervised, training
frames); stages are cached in ``WORK/cache-<seed>`` under keys that include the masks and their
noise, so sources never share a result. DPSNR needs a training per source and street and is not
measured here (``bench_deformation.py --variants self-supervised`` trains the lidar-motion one).
"""

from __future__ import annotations

import time
from dataclasses import replace

from idsplat_ns.eval.tracking import aggregate
from idsplat_ns.eval.trajectory_eval import flatten_metrics, tracking_summary
from idsplat_ns.instances.motion_tracks import LidarMotionConfig
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.masks.perturb import MaskNoiseConfig
from idsplat_ns.instances.modes import instance_tracks_for_mode
from idsplat_ns.instances.runner import PreprocessConfig
from idsplat_ns.model.trajectories import InstanceTrajectories

from bench.streets import street_arguments, training_streets

GT = PreprocessConfig(masks=MaskConfig(kind="ground-truth"))
NO_NOISE = MaskNoiseConfig(max_edge_px=0, miss_probability=0.0, spurious_per_sequence=0, swap_probability=0.0)
SOURCES = {
    "ground truth": GT,
    "GT, edges ±3 px, 10 % missed, 1 false positive": replace(GT, mask_noise=MaskNoiseConfig()),
    "GT, edges ±6 px, 30 % missed, 3 false positives": replace(
        GT, mask_noise=MaskNoiseConfig(max_edge_px=6, miss_probability=0.3, spurious_per_sequence=3)),
    "GT, identities swapped in 10 % of images": replace(GT, mask_noise=replace(NO_NOISE, swap_probability=0.1)),
    "lidar motion": PreprocessConfig(masks=MaskConfig(kind="lidar-motion")),
    "lidar motion, points painted back through its masks": PreprocessConfig(
        masks=MaskConfig(kind="lidar-motion", lidar_motion=LidarMotionConfig(lift_own_points=False))),
}


def main() -> None:
    ap = street_arguments(__doc__.splitlines()[0])
    ap.set_defaults(seeds=[100, 101, 102, 103, 104])
    ap.add_argument("--sources", nargs="+", default=list(SOURCES), metavar="NAME",
                    help="rows to measure, by name (default: all of " + ", ".join(SOURCES).replace("%", "%%") + ")")
    args = ap.parse_args()
    unknown = [n for n in args.sources if n not in SOURCES]
    if unknown:
        raise SystemExit(f"--sources: unknown {unknown}; choose from {list(SOURCES)}")
    sources = {name: SOURCES[name] for name in args.sources}
    per_source: dict[str, list] = {name: [] for name in sources}
    seconds: dict[str, list[float]] = {name: [] for name in sources}
    for seed, scene, train, cache in training_streets(args, "idsplat_masks_"):
        for name, config in sources.items():
            if config.mask_noise is not None:  # a different damage per street
                config = replace(config, mask_noise=replace(config.mask_noise, seed=seed))
            t0 = time.perf_counter()
            tracks = instance_tracks_for_mode(scene, "self-supervised", train, config, cache)
            seconds[name].append(time.perf_counter() - t0)
            summary = tracking_summary(scene, InstanceTrajectories.from_instance_tracks(tracks).positions_at)
            per_source[name].append(summary)
            flat = flatten_metrics(summary)
            print(f"seed {seed}, {name}: MOTA@2m {flat.get('mota@2m', float('nan')):.3f}, "
                  f"{len(tracks.instances)} dynamic instances, {seconds[name][-1]:.1f} s", flush=True)
    print("\n| masks | MOTA@2m | MOTP@2m m | precision | recall | ID switches | preprocessing s (mean) |")
    print("|---|---|---|---|---|---|---|")
    for name, summaries in per_source.items():
        flat = flatten_metrics(aggregate(summaries))
        print(f"| {name} | {flat['mota@2m']:.3f} | {flat['motp@2m']:.3f} | {flat['precision@2m']:.3f} "
              f"| {flat['recall@2m']:.3f} | {flat['id_switches@2m']:.0f} | {sum(seconds[name]) / len(seconds[name]):.1f} |")


if __name__ == "__main__":
    main()
