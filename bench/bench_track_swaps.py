"""Which part of the self-supervised tracks costs DPSNR against the annotated ones: the poses, or
the frames the instances exist in. Each built-in street is trained (``ns-train idsplat-fast``, then
``ns-eval``) four ways:

- ``self-supervised``: the tracks ns-train builds (``idsplat-preprocess --export``'s), read back through
  ``--pipeline.datamanager.import-tracks`` (the same instances ns-train would build);
- ``true-poses``: the same instances (their canonical points, their frames) moved as the annotated
  box that holds most of their points moves;
- ``true-spans``: as ``true-poses``, over every frame of that box's track (the pieces of one
  object kept as its piece with the most points);
- ``oracle``: the annotated tracks (``--pipeline.datamanager.instance-mode oracle``).

Then one row per (street, variant) and, per object name (the built-in street's manoeuvre), its
DPSNR in each variant and its frames lost by the self-supervised tracks.

    .venv/bin/python -m bench.bench_track_swaps --preset hard --seeds 1 2 --jobs 2 --work W --out T.md
"""

from __future__ import annotations

import argparse
import copy
import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from idsplat_ns.data.geometry import invert_pose
from idsplat_ns.data.split import split_frames
from idsplat_ns.eval.instance_pose_errors import match_instance
from idsplat_ns.instances.modes import instance_tracks_for_mode
from idsplat_ns.instances.runner import PreprocessConfig
from idsplat_ns.instances.tracks import InstanceTracks, fill_invalid_poses
from idsplat_ns.instances.tracks_json import write_tracks_json
from idsplat_ns.nerfstudio.builtin_scene import builtin_street, instance_cache_dir
from idsplat_ns.nerfstudio.dataparser import AutoDataParserConfig

from bench.bench_modes import train_and_evaluate
from bench.streets import parse_settings

VARIANTS = ("self-supervised", "true-poses", "true-spans", "oracle")


def with_true_motion(tracks: InstanceTracks, scene, whole_span: bool) -> InstanceTracks:
    """``tracks`` (made on ``scene``, the training frames) with each instance matched to an annotated
    track moved as that track's box moves from the instance's canonical frame; ``whole_span``: over
    every frame the box exists in, and only the matched piece with the most points per box."""
    out = copy.deepcopy(tracks)
    owner: dict[int, tuple[int, int]] = {}  # annotated track -> (instance id, canonical points)
    matched = {}
    for inst in out.instances:
        ti = match_instance(scene, inst)
        matched[inst.instance_id] = ti
        if ti is not None and (ti not in owner or len(inst.canonical_points) > owner[ti][1]):
            owner[ti] = (inst.instance_id, len(inst.canonical_points))
    keep = []
    for inst in out.instances:
        ti = matched[inst.instance_id]
        if ti is None:
            keep.append(inst)
            continue
        if whole_span and owner[ti][0] != inst.instance_id:
            continue
        track = scene.tracks[ti]
        c = inst.canonical_frame
        anchor = invert_pose(track.pose_at_frame(int(scene.frame_indices[c]))) @ inst.poses[c]  # canonical in the box
        for k, f in enumerate(scene.frame_indices):
            box = track.pose_at_frame(int(f))
            if box is not None and (inst.valid[k] or whole_span):
                inst.poses[k], inst.valid[k] = box @ anchor, True
        inst.poses = fill_invalid_poses(inst.poses, inst.valid)
        inst.measured_valid = None
        keep.append(inst)
    out.instances = keep
    return out


def write_variants(preset: str, seed: int, work: Path, config: PreprocessConfig) -> dict[str, Path]:
    """The three tracks files of one street (``self-supervised``, ``true-poses``, ``true-spans``)."""
    street = builtin_street(preset, seed)
    folder = work / f"{preset}-{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    files = {v: folder / f"{v}.json" for v in VARIANTS[:3]}
    if all(p.is_file() for p in files.values()):
        return files
    # As idsplat-preprocess (and ns-train) does it, on the street loaded once.
    parser = AutoDataParserConfig(data=street).resolved()
    scene = parser.load_scene()
    train_idx, _ = split_frames(scene.num_frames, parser.train_fraction, parser.eval_every)
    frames = set(scene.frame_indices[train_idx].tolist())
    train = scene.subset(frames)
    tracks = instance_tracks_for_mode(scene, "self-supervised", frames, config, instance_cache_dir(scene.name))
    for variant, tracks_of in (("self-supervised", tracks), ("true-poses", with_true_motion(tracks, train, False)),
                               ("true-spans", with_true_motion(tracks, train, True))):
        write_tracks_json(files[variant], tracks_of, train)
    return files


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="hard")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--steps", type=int, default=1500, help="training steps (idsplat-fast)")
    ap.add_argument("--jobs", type=int, default=2, help="trainings at once (each on one thread when more than 1)")
    ap.add_argument("--work", type=Path, default=Path("outputs/track_swaps"))
    ap.add_argument("--set", nargs="*", default=[], metavar="PATH=VALUE", help="preprocessing settings changed")
    ap.add_argument("--out", type=Path, default=None, help="also write the tables here (markdown)")
    args = ap.parse_args()
    config = PreprocessConfig()
    for change in parse_settings(args.set):
        config = change(config)
    files = {seed: write_variants(args.preset, seed, args.work, config) for seed in args.seeds}
    keys = [(seed, v) for seed in args.seeds for v in VARIANTS]

    def run(key):
        seed, variant = key
        options = "" if variant == "oracle" else f"--pipeline.datamanager.import-tracks {files[seed][variant]}"
        ns = argparse.Namespace(jobs=args.jobs, skip_existing=True, steps=args.steps, train_args=options,
                                output_dir=args.work / "runs" / variant)
        return train_and_evaluate(args.preset, seed, "oracle" if variant == "oracle" else "self-supervised", ns)

    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = dict(zip(keys, pool.map(run, keys)))
    lines = [f"`{args.preset}` streets {' '.join(map(str, args.seeds))}, idsplat-fast {args.steps} steps", "",
             "| street | variant | PSNR | DPSNR | MOTA@2m | lidar depth m² |", "|---|---|---|---|---|---|"]
    for (seed, variant), r in results.items():
        lines.append(f"| {seed} | {variant} | {r['psnr']:.2f} | {r['dpsnr']:.2f} | {r['mota@2m']:.3f} | "
                     f"{r['lidar_depth_median_sq_err']:.3f} |")
    per_object: dict[str, dict[str, list]] = {}
    lost: dict[str, list[int]] = {}
    for (seed, variant), r in results.items():
        for o in r.get("objects", []):
            name = f"{o['name']} ({o['class']})"
            if o["dpsnr"] is not None:
                per_object.setdefault(name, {}).setdefault(variant, []).append(o["dpsnr"])
            if variant == "self-supervised":
                counts = lost.setdefault(name, [0, 0])
                counts[0] += o["frames_lost"]
                counts[1] += o["frames"]
    lines += ["", "| object | self-supervised: lost | " + " | ".join(f"{v}: DPSNR" for v in VARIANTS) + " |",
              "|---|---|" + "---|" * len(VARIANTS)]
    for name in sorted(per_object):
        cells = [f"{np.mean(per_object[name][v]):.2f}" if v in per_object[name] else "-" for v in VARIANTS]
        counts = lost.get(name, [0, 0])
        lines.append(f"| {name} | {counts[0]}/{counts[1]} | " + " | ".join(cells) + " |")
    text = "\n".join(lines)
    print("\n" + text)
    if args.out is not None:
        args.out.write_text(text + "\n")
        (args.out.with_suffix(".json")).write_text(json.dumps({f"{s}/{v}": r for (s, v), r in results.items()}, default=str))


if __name__ == "__main__":
    main()
