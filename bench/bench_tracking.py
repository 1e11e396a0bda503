"""Tracking quality of the self-supervised instance tracks *before* training (what the model
starts from), on the synthetic street: CLEAR-MOT against the moving vehicles (the observed
protocol of ``eval/trajectory_eval.py``, and all annotated ones), a per-object table (matched
instance, static/dynamic decision, offset of the canonical origin), ns-eval's per-object diagnosis
(frames lost, lost within 10 m of the ego, longest gap, tracks per object) and, over all seeds,
the same per manoeuvre, with the preprocessing time per instance.

    .venv/bin/python -m bench.bench_tracking --preset small --seeds 0 1 [--masks ground-truth]
    .venv/bin/python -m bench.bench_tracking --preset hard --seeds 100 101 102 103 --out T.md

Uses the same frames as training (the dataparser's split) and the same preprocessing as
``ns-train idsplat`` (masks from lidar motion; ``--masks ground-truth``: the generator's 2D masks).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from idsplat_ns.eval.object_diagnosis import ObjectRecord, diagnose_objects
from idsplat_ns.eval.tracking import aggregate
from idsplat_ns.eval.trajectory_eval import flatten_metrics, tracking_summary
from idsplat_ns.instances.modes import instance_tracks_for_mode
from idsplat_ns.instances.runner import PreprocessConfig
from idsplat_ns.model.trajectories import InstanceTrajectories

from bench.streets import parse_settings, street_arguments, training_streets


def _object_rows(scene, tracks) -> list[str]:
    """One row per annotated vehicle: the instance whose points it holds most, its fate, offset."""
    rows = []
    insts = {i.instance_id: (i, "dynamic") for i in tracks.instances}
    insts.update({i.instance_id: (i, "static") for i in tracks.static_instances})
    for trk in scene.tracks:
        if trk.group != "vehicle":
            continue
        best, best_d = None, np.inf
        for iid, (inst, fate) in insts.items():
            k = np.flatnonzero(inst.valid)
            if len(k) == 0:
                continue
            ds = []
            for f_local in k:
                f = int(tracks.frame_indices[f_local])
                pose = trk.pose_at_frame(f)
                if pose is not None:
                    ds.append(np.linalg.norm(inst.poses[f_local, :3, 3] - pose[:3, 3]))
            if ds and np.median(ds) < best_d:
                best, best_d = (iid, fate, inst), float(np.median(ds))
        if best is None:
            rows.append(f"{trk.track_id:>12} {'moving' if trk.moving else 'parked':>7} {'-':>5} {'missed':>8}")
            continue
        iid, fate, inst = best
        rows.append(f"{trk.track_id:>12} {'moving' if trk.moving else 'parked':>7} {iid:>5} {fate:>8}"
                    f" {best_d:>8.2f} {inst.displacement():>8.2f} {inst.num_valid:>6}")
    return rows


def main() -> None:
    ap = street_arguments(__doc__.splitlines()[0])
    ap.add_argument("--masks", default="auto", choices=["auto", "lidar-motion", "ground-truth"],
                    help="mask source (auto: lidar-motion on the built-in street; ground-truth: its own 2D masks)")
    ap.add_argument("--out", type=Path, default=None, help="also write the per-seed and per-manoeuvre tables here (markdown)")
    ap.add_argument("--set", nargs="*", default=[], metavar="PATH=VALUE",
                    help="preprocessing settings changed, by their dotted names (masks.lidar_motion.max_extent=14)")
    args = ap.parse_args()
    from idsplat_ns.instances.masks.config import MaskConfig

    preprocess = PreprocessConfig(masks=MaskConfig(kind=args.masks))
    for change in parse_settings(args.set):
        preprocess = change(preprocess)
    per_seq, per_seq_all, lines = [], [], []
    records: list[tuple[int, ObjectRecord]] = []
    all_vehicles: list[ObjectRecord] = []
    total_s = 0.0
    for seed, scene, train, cache in training_streets(args, "idsplat_track_"):
        t0 = time.perf_counter()
        tracks = instance_tracks_for_mode(scene, "self-supervised", train, preprocess, cache)
        seconds = time.perf_counter() - t0
        traj = InstanceTrajectories.from_instance_tracks(tracks)
        summary = tracking_summary(scene, traj.positions_at)
        every = tracking_summary(scene, traj.positions_at, observed=None)
        per_seq.append(summary)
        per_seq_all.append(every)
        # Every frame, as ns-eval counts them: held-out frames between training frames are interpolated.
        objects = diagnose_objects(scene, traj.positions_at)
        records += [(seed, r) for r in objects]
        n_inst = len(tracks.instances) + len(tracks.static_instances)
        print(f"\nseed {seed}: preprocessing {seconds:.1f} s ({seconds / max(n_inst, 1):.1f} s an instance), "
              f"{len(tracks.instances)} dynamic, {len(tracks.static_instances)} static instances")
        print(f"{'object':>12} {'truth':>7} {'inst':>5} {'decided':>8} {'med.err':>8} {'displ.':>8} {'valid':>6}")
        print("\n".join(_object_rows(scene.subset(train), tracks)))
        _print_metrics(f"seed {seed}", summary)
        _print_metrics(f"seed {seed} (all)", every)
        vehicles = [r for r in objects if r.group == "vehicle"]
        lines.append(_row(str(seed), summary, vehicles, f"{seconds:.1f} | {seconds / max(n_inst, 1):.2f}"))
        all_vehicles += vehicles
        total_s += seconds
    if len(per_seq) > 1:
        _print_metrics("all seeds", aggregate(per_seq))
        _print_metrics("all seeds (all)", aggregate(per_seq_all))
        lines.append(_row("all", aggregate(per_seq), all_vehicles, f"{total_s:.1f} |"))
    table = "\n".join([
        f"Self-supervised tracks before training, `{args.preset}` seeds {' '.join(map(str, args.seeds))}, training "
        "frames' tracks at every frame, 2 m; vehicles only in the counts", "",
        "| seed | MOTA@2m | MOTP@2m | IDF1@2m | ID switches | fragmentations | frames lost | lost within 10 m | "
        "gaps > 3 frames | preprocessing s | s an instance |",
        "|---|---|---|---|---|---|---|---|---|---|---|", *lines, "", distance_table(all_vehicles), "",
        manoeuvre_table(records)])  # fmt: skip
    print("\n" + table)
    if args.out is not None:
        args.out.write_text(table + "\n")


def _row(name: str, summary, vehicles: list["ObjectRecord"], seconds: str) -> str:
    """One row of the per-seed table: CLEAR-MOT and identity metrics at 2 m, then the vehicles'
    frames lost (all, and within 10 m of the ego) and long gaps, then the time."""
    flat = flatten_metrics(summary)
    m = summary[2.0]
    return (f"| {name} | {flat.get('mota@2m', float('nan')):.3f} | {flat.get('motp@2m', float('nan')):.2f} | "
            f"{flat.get('idf1@2m', float('nan')):.3f} | {m.num_switches} | {m.num_fragmentations} | "
            f"{sum(r.frames_lost for r in vehicles)} / {sum(len(r.frames) for r in vehicles)} | "
            f"{sum(r.frames_lost_near for r in vehicles)} / {sum(r.frames_near for r in vehicles)} | "
            f"{sum(r.longest_lost > 3 for r in vehicles)} | {seconds} |")


DISTANCE_BANDS = (0.0, 10.0, 20.0, 40.0, 60.0, 80.0)
"""Metres from the ego's lidar: the bands of :func:`distance_table`."""


def distance_table(vehicles: list["ObjectRecord"]) -> str:
    """The vehicles' frames lost and the median position error of the frames tracked, against
    their distance to the ego, over all seeds: where tracking fails (passes next to the ego, or
    far away where lidar returns thin out) and where its poses are off (near the ego an error
    covers the most pixels)."""
    bands = len(DISTANCE_BANDS) - 1
    lost, seen = np.zeros(bands, int), np.zeros(bands, int)
    errors: list[list[float]] = [[] for _ in range(bands)]
    along: list[list[float]] = [[] for _ in range(bands)]
    for r in vehicles:
        band = np.clip(np.searchsorted(DISTANCE_BANDS, r.distance_to_ego, side="right") - 1, 0, bands - 1)
        np.add.at(seen, band, 1)
        np.add.at(lost, band, ~np.asarray(r.tracked, bool))
        for b, tracked, err, err_along in zip(band, r.tracked, r.error, r.along_error, strict=True):
            if tracked and np.isfinite(err):
                errors[b].append(float(err))
                along[b].append(abs(float(err_along)))
    names = [f"{a:.0f}-{b:.0f} m" for a, b in zip(DISTANCE_BANDS[:-1], DISTANCE_BANDS[1:])]

    def row(title: str, values: list[list[float]], q: float) -> str:
        return f"| {title} | " + " | ".join(f"{np.quantile(v, q):.2f}" if v else "-" for v in values) + " |"

    return "\n".join(["| vehicles | " + " | ".join(names) + " |", "|---|" + "---|" * len(names),
                      "| frames lost / counted | " + " | ".join(f"{a} / {b}" for a, b in zip(lost, seen)) + " |",
                      row("median error of tracked frames, m", errors, 0.5),
                      row("90th percentile of that error, m", errors, 0.9),
                      row("90th percentile of its part along the heading, m", along, 0.9)])


def manoeuvre_table(records: list[tuple[int, "ObjectRecord"]]) -> str:
    """Per object name (the built-in street's manoeuvre) over all seeds: objects, frames lost (near the
    ego), objects with a gap of more than 3 frames, objects split into several tracks."""
    by_name: dict[str, list] = {}
    for _, r in records:
        by_name.setdefault(f"{r.name} ({r.group})", []).append(r)
    rows = ["| object | count | frames lost | lost within 10 m | gaps > 3 frames | split |", "|---|---|---|---|---|---|"]
    for name, rs in sorted(by_name.items(), key=lambda kv: -sum(r.frames_lost for r in kv[1])):
        rows.append(f"| {name} | {len(rs)} | {sum(r.frames_lost for r in rs)} / {sum(len(r.frames) for r in rs)} | "
                    f"{sum(r.frames_lost_near for r in rs)} / {sum(r.frames_near for r in rs)} | "
                    f"{sum(r.longest_lost > 3 for r in rs)} | {sum(r.fragments > 1 for r in rs)} |")  # fmt: skip
    return "\n".join(rows)


def _print_metrics(title: str, summary) -> None:
    flat = flatten_metrics(summary)
    keys = ("mota", "motp", "recall", "precision", "objects")
    print(f"  {title:<15}" + "  ".join(f"{k}={v:.3f}" for k, v in flat.items() if k.startswith(keys)))


if __name__ == "__main__":
    main()
