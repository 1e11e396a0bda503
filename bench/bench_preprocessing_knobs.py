"""How instance preprocessing's knobs trade its time against tracking quality: the built-in streets
preprocessed as ``ns-train idsplat`` does without model files (self-supervised, lidar-motion masks,
training frames), each knob moved one at a time from the default. Per variant: MOTA@2m, MOTP@2m,
precision, recall and identity switches of the moving vehicles (the observed protocol, pooled over
the streets), the mean preprocessing seconds per street and the seconds of each stage.

    .venv/bin/python -m bench.bench_preprocessing_knobs --preset tiny --seeds 3 --variants default "features fpfh"
    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 NUMBA_NUM_THREADS=1 nice -n 10 .venv/bin/python \\
        bench/bench_preprocessing_knobs.py --preset small --seeds 100 101 102 103 104 --work WORK --out TABLE.md

Seeds 100 and up are the ones to report (the lower ones are the development streets).

Variants: ``default`` (the paper's settings; features ``auto``, which is DAISY on these streets),
RANSAC (``trajectory.registration``: confidence 0.99, max_iterations 1000 or 10000, max_points
1000; icp_iterations 0 turns the ICP refinement off), smoothing (``smoothing.final_iterations`` 3
or 1, or the stage off) and features (``fpfh``, ``rgb``). DINOv3, the paper's features, needs model
weights that cannot be downloaded here and is left out.

Each street is preprocessed by ``run_preprocessing`` on the training frames, as
``instance_tracks_for_mode(scene, "self-supervised", ...)`` calls it (called directly here for its
stage timings). Stages are cached in ``WORK/cache-<seed>`` and shared between variants: each
stage's key holds its settings and the keys of the stages before it, so a variant recomputes the
stage its knob is in and every stage after it, and reuses the ones before (the masks, computed once
per street). The seconds reported are those of computing: a stage a variant reads from the cache
is counted with the seconds it took when it was computed in this run on the same street (the same
cache file), so every row is the time of a whole preprocessing from nothing. Each run checks that
the stage a variant's knob is in was not read from the default's cache file (a knob missing from
its stage's key would be). A ``WORK`` reused from an earlier run holds the stages already: their
seconds are then load times, marked ``*``; use a fresh ``WORK`` for timings. With
``OMP_NUM_THREADS`` set, torch and OpenCV use that many threads too. open3d (used by the registration
and FPFH) is imported before the first timing.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Optional

import cv2
import torch

from idsplat_ns.eval.tracking import aggregate
from idsplat_ns.eval.trajectory_eval import flatten_metrics, tracking_summary
from idsplat_ns.instances import runner
from idsplat_ns._compat.libusb import import_open3d
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.modes import ground_truth_masks
from idsplat_ns.instances.runner import PreprocessConfig, PreprocessResult, run_preprocessing
from idsplat_ns.model.trajectories import InstanceTrajectories

from bench.streets import street_arguments, training_streets

DEFAULT = PreprocessConfig(masks=MaskConfig(kind="lidar-motion"))


def _registration(**changes) -> PreprocessConfig:
    reg = replace(DEFAULT.trajectory.registration, **changes)
    return replace(DEFAULT, trajectory=replace(DEFAULT.trajectory, registration=reg))


def _smoothing(**changes) -> PreprocessConfig:
    return replace(DEFAULT, smoothing=replace(DEFAULT.smoothing, **changes))


VARIANTS = {
    "default": DEFAULT,
    "RANSAC confidence 0.99": _registration(confidence=0.99),
    "RANSAC max_iterations 1000": _registration(max_iterations=1000),
    "RANSAC max_iterations 10000": _registration(max_iterations=10_000),
    "RANSAC max_points 1000": _registration(max_points=1000),
    "ICP off (icp_iterations 0)": _registration(icp_iterations=0),
    "smoothing final_iterations 3": _smoothing(final_iterations=3),
    "smoothing final_iterations 1": _smoothing(final_iterations=1),
    "smoothing off": replace(DEFAULT, smoothing=None),
    "features fpfh": replace(DEFAULT, features=replace(DEFAULT.features, kind="fpfh")),
    "features rgb": replace(DEFAULT, features=replace(DEFAULT.features, kind="rgb")),
}
STAGES = ["mask generation", "point painting", "features", "registration", "smoothing"]  # the table's stage columns
CACHE_PREFIX = {"lifting": "point painting", "features": "features", "registration": "registration",
                "smoothing": "smoothing"}  # cache file name -> stage


def changed_stage(config: PreprocessConfig) -> Optional[str]:
    """The first stage whose settings differ from the default's (None for the default)."""
    for field, stage in (("masks", "mask generation"), ("mask_noise", "mask generation"), ("lifting", "point painting"),
                         ("features", "features"), ("trajectory", "registration"), ("static", "smoothing"),
                         ("smoothing", "smoothing")):
        if getattr(config, field) != getattr(DEFAULT, field):
            return stage
    return None


def preprocess(scene, train: set[int], config: PreprocessConfig, cache: Path) -> tuple[PreprocessResult, dict[str, str]]:
    """``run_preprocessing`` as ``instance_tracks_for_mode`` (self-supervised) runs it, and the cache
    file of each cached stage (stage -> file name; the masks by their settings)."""
    files = {"mask generation": f"masks {config.masks!r} {config.mask_noise!r}"}
    original = runner._cached_file

    def recording(path: Path, *args, **kwargs):
        files[CACHE_PREFIX[path.name.split("-", 1)[0]]] = path.name
        return original(path, *args, **kwargs)

    runner._cached_file = recording
    try:
        result = run_preprocessing(scene.subset(train), ground_truth_masks(scene, config), cache,
                                   progress=False, verbose=False)
    finally:
        runner._cached_file = original
    return result, files


def main() -> None:
    ap = street_arguments(__doc__.splitlines()[0])
    ap.set_defaults(seeds=[100, 101, 102, 103, 104])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), metavar="NAME",
                    help=f"rows to measure, by name (default: all of {list(VARIANTS)})")
    ap.add_argument("--out", type=Path, default=None, help="also write the table to this file")
    args = ap.parse_args()
    unknown = [n for n in args.variants if n not in VARIANTS]
    if unknown:
        raise SystemExit(f"--variants: unknown {unknown}; choose from {list(VARIANTS)}")
    if os.environ.get("OMP_NUM_THREADS"):
        threads = int(os.environ["OMP_NUM_THREADS"])
        torch.set_num_threads(threads)
        cv2.setNumThreads(threads)
    import_open3d()  # before any timing (about 1.5 s), not in the first variant's registration or features
    variants = {name: VARIANTS[name] for name in args.variants}
    summaries: dict[str, list] = {name: [] for name in variants}
    stage_seconds: dict[str, dict[str, list[float]]] = {name: {s: [] for s in STAGES} for name in variants}
    totals: dict[str, list[float]] = {name: [] for name in variants}
    loaded_only = False  # some stage was read from a cache this run did not write
    key_problems: list[str] = []
    for seed, scene, train, cache in training_streets(args, "idsplat_knobs_"):
        computed: dict[str, float] = {}  # cache file -> seconds it took to compute on this street
        files_of: dict[str, dict[str, str]] = {}  # variant -> its stages' cache files on this street
        for name, config in variants.items():
            result, files = preprocess(scene, train, config, cache)
            total = 0.0
            for t in result.timings:
                key = files.get(t.name)
                seconds = t.seconds
                if key is not None and not t.cached:
                    computed[key] = t.seconds
                elif key is not None:  # read from the cache: count the seconds it took to compute
                    seconds = computed.get(key, t.seconds)
                    loaded_only |= key not in computed
                total += seconds
                if t.name in STAGES:
                    stage_seconds[name][t.name].append(seconds)
            totals[name].append(total)
            files_of[name] = files
            summary = tracking_summary(scene, InstanceTrajectories.from_instance_tracks(result.tracks).positions_at)
            summaries[name].append(summary)
            flat = flatten_metrics(summary)
            stages = ", ".join(f"{t.name} {t.seconds:.1f}{' (cached)' if t.cached else ''}" for t in result.timings)
            print(f"seed {seed}, {name}: MOTA@2m {flat.get('mota@2m', float('nan')):.3f}, "
                  f"MOTP@2m {flat.get('motp@2m', float('nan')):.3f} m, ID switches {flat.get('id_switches@2m', 0):.0f}, "
                  f"{len(result.tracks.instances)} dynamic instances, {total:.1f} s from nothing "
                  f"({result.total_seconds:.1f} s this call: {stages})", flush=True)
        default_files = next((f for n, f in files_of.items() if variants[n] == DEFAULT), None)
        for name, files in files_of.items():
            stage = changed_stage(variants[name])
            if default_files is not None and stage is not None and files.get(stage) == default_files.get(stage):
                key_problems.append(f"seed {seed}, {name}: its {stage} stage read the default's cache file {files[stage]}")
                print(f"WARNING: {key_problems[-1]}", flush=True)
    mark = "*" if loaded_only else ""
    lines = ["| variant | MOTA@2m | MOTP@2m m | precision | recall | ID switches | preprocessing s (mean) | "
             + " | ".join(f"{s} s" for s in STAGES) + " |",
             "|---" * (7 + len(STAGES)) + "|"]
    for name, per_street in summaries.items():
        flat = flatten_metrics(aggregate(per_street))
        cells = [f"{sum(v) / len(v):.2f}{mark}" if v else "-" for v in stage_seconds[name].values()]
        lines.append(f"| {name} | {flat['mota@2m']:.3f} | {flat['motp@2m']:.3f} | {flat['precision@2m']:.3f} "
                     f"| {flat['recall@2m']:.3f} | {flat['id_switches@2m']:.0f} "
                     f"| {sum(totals[name]) / len(totals[name]):.1f}{mark} | " + " | ".join(cells) + " |")
    notes = [f"streets: preset {args.preset}, seeds {args.seeds}; seconds: computing each stage (a stage shared "
             "with an earlier variant counted with its own computing time on the same street)"]
    if loaded_only:
        notes.append("*: some stages were read from a cache this run did not write: load times, not computing times")
    notes += [f"CACHE KEY PROBLEM: {p}" for p in key_problems]
    table = "\n".join(lines + [""] + notes)
    print("\n" + table, flush=True)
    if args.out is not None:
        args.out.write_text(table + "\n")


if __name__ == "__main__":
    main()
