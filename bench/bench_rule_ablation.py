"""Ablation of the preprocessing rules that go beyond the paper: each variant is the default
``PreprocessConfig`` with ONE rule switched off (on, for the one rule off by default; ``paper``:
all of them off at once), run on built-in
streets no rule was tuned on (seeds 100-109, fixed before any result was seen), self-supervised
with the generator's ground-truth 2D masks. Per variant and street: MOTA@2m and MOTP@2m of the
moving vehicles (the observed protocol of ``eval/trajectory_eval.py``, as ``bench_tracking.py``),
the mean box-corner error of the moving vehicles' final poses at the training frames
(``tracking_quality.evaluate``) and the stage seconds. Prints a markdown
table with a verdict per rule (see ``_verdict``) and writes the per-street results to ``--json``.

    nice -n 5 env OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python -m bench.bench_rule_ablation \\
        --preset small --seeds 100 101 102 103 104 105 106 107 108 109 --work /tmp/ablation \\
        --json /tmp/ablation/rule_ablation.json

The preprocessing is that of ``instance_tracks_for_mode(scene, "self-supervised", ...)`` with
``--masks.kind ground-truth`` (``ground_truth_masks`` + ``run_preprocessing`` on the training
frames of ``_streets.training_streets``), called directly for its stage timings. Stages are cached
in ``WORK/cache-<seed>`` under keys that hash every setting they read (registration: the whole
``TrajectoryConfig``; smoothing: the registration key, ``StaticConversionConfig``, the dynamic
instance ids and the whole ``SmoothingConfig``), so a variant that only changes smoothing reuses
the default registration and never another variant's result. Each (variant, street) result is
also kept in ``WORK/results`` (keyed by the variant's full config), so an interrupted run resumes
where it stopped. ``--variants`` picks rows (``default`` is always run: the deltas are against it);
``--registration-seeds`` runs the variants that change registration or lifting on fewer streets.
"""

from __future__ import annotations

import json
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from idsplat_ns.eval.tracking import TrackingMetrics, aggregate
from idsplat_ns.eval.trajectory_eval import flatten_metrics
from idsplat_ns.instances.cache import hash_json
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.runner import PreprocessConfig
from idsplat_ns.instances.trajectory_passes import TRACK_PASSES

from bench.streets import setting_of, street_arguments, training_streets
from bench.tracking_quality import evaluate

RESULTS_VERSION = 1  # bumped when what a stored (variant, street) result holds changes
MOTA_TOL = 0.002  # a street's MOTA@2m counts as worse/better beyond this
CORNER_TOL = 0.01  # a street's mean corner error counts as worse/better beyond this fraction
MOTA_EFFECT = 0.01  # verdict margins: mean MOTA@2m change ...
CORNER_EFFECT = 0.03  # ... or mean relative corner-error change


@dataclass(frozen=True)
class Rule:
    """One rule beyond the paper and the setting that switches it off."""

    name: str  # variant name (the rule off)
    stage: str  # the first cached stage it changes: smoothing (or later) | registration | lifting
    path: str  # dotted config field, as the docs name it (``registration.*`` is ``trajectory.registration.*``)
    value: object  # the value that switches the rule off (on, for a rule off by default)
    what: str  # what the rule does, one line
    default_on: bool = True  # False: the rule is off by default and the variant switches it on

    @property
    def setting(self) -> str:
        value = f"{self.value:g}" if isinstance(self.value, float) else str(self.value)
        return f"{self.path}={value}"

    def off(self, c: PreprocessConfig) -> PreprocessConfig:
        return setting_of(self.path, self.value)(c)


RULES = [
    # Smoothing (registration reused from the cache).
    Rule("no-vertical-motion", "smoothing", "smoothing.motion_vertical_sigma", None,
         "CT motion factor's vertical translation per step held to 0.02 m (paper: isotropic 0.2 m)"),
    Rule("no-tilt-motion", "smoothing", "smoothing.motion_tilt_sigma", None,
         "CT motion factor's roll/pitch change per step held to 0.01 rad (paper: 0.1 rad)"),
    Rule("no-turning-curvature", "smoothing", "smoothing.turning_curvature_sigma", None,
         "curvature prior and walk freed for vehicles whose registrations turn by 30 deg or more"),
    Rule("no-heading-prior", "smoothing", "smoothing.heading_prior_sigma", None,
         "direction of travel tied to the vehicle's box axis from its points' vertical faces"),
    Rule("no-ground", "smoothing", "smoothing.ground_height_walk_rate", None,
         "vehicle height follows the lidar ground under it"),
    Rule("no-span-limit", "smoothing", "smoothing.span_max_distance", None,
         "measurements > 1 m from the smoothed track do not extend the instance's span"),
    Rule("no-gross-yaw", "smoothing", "smoothing.gross_yaw_deviation", None,
         "measurements > 90 deg off their neighbours' yaw are outliers from the start"),
    Rule("with-outlier-point-drop", "smoothing", "smoothing.drop_outlier_points", True,
         "points of outlier measurements leave the canonical point set (off by default)", default_on=False),
    Rule("frame-times", "smoothing", "smoothing.measurement_times", False,
         "registrations placed at their points' mean lidar ray time, not the frame time"),
    Rule("no-repose", "smoothing", "smoothing.repose_points", False,
         "canonical points re-derived with the smoothed pose at their own ray time"),
    Rule("no-degenerate", "smoothing", "smoothing.degenerate_directions", False,
         "directions a view's surfaces do not measure get a 3 m sigma (and the three rules below)"),
    Rule("no-vertical-cap", "smoothing", "smoothing.degenerate_vertical_sigma", None,
         "an unmeasured vertical direction is never freer than 0.3 m"),
    Rule("no-sparse-views", "smoothing", "smoothing.degenerate_sparse_frame_points", None,
         "views of < 100 points leave every unmeasured direction to the motion (with a heading prior)"),
    Rule("two-sided", "smoothing", "smoothing.degenerate_one_sided", False,
         "an axis measured only through the front in some views and the rear in others is left to the motion"),
    Rule("no-reconverge", "smoothing", "smoothing.reconverge_below_inlier_fraction", 0.0,
         "first pass iterated to convergence when it keeps < 50 % of the measurements"),
    # After registration, not cached (static conversion changes the smoothing key through the dynamic set).
    Rule("no-world-overlap", "smoothing", "static.use_world_overlap", False,
         "instances whose points agree across frames without motion are made static"),
    Rule("no-amodal", "smoothing", "amodal.enabled", False,
         "canonical origin moved to the middle of the whole vehicle (class size, sensor side)"),
    Rule("no-contained-parts", "smoothing", "amodal.parts.enabled", False,
         "instances whose points stay inside a long vehicle's completed box, moving with it, folded into it"),
    # Registration (a registration of its own per street).
    Rule("no-back-face", "registration", "registration.back_face_tolerance", None,
         "fitness inliers only on source surfaces facing the target's sensor"),
    Rule("no-tilt-limit", "registration", "registration.max_tilt", None,
         "RANSAC hypotheses tilting the up axis > 20 deg are not considered"),
    Rule("no-rescore", "registration", "registration.rescore_top_k", 1,
         "the 8 best hypotheses by correspondence inliers re-scored by fitness (paper: the best one)"),
    Rule("no-refit", "registration", "registration.refine_iterations", 0,
         "the winner refitted (Umeyama) on all its consistent correspondences, twice"),
    Rule("no-icp", "registration", "registration.icp_iterations", 0,
         "point-to-plane ICP refinement of the RANSAC winner"),
    # The track builder's passes beyond the paper's, each with the setting that switches it off.
    *(Rule(f"no-{p.name}", "registration", f"trajectory.{p.switch[0]}", p.switch[1], p.what)
      for p in TRACK_PASSES if p.switch is not None),
    Rule("no-chain-centroid-velocity", "registration", "trajectory.chain_centroid_velocity", False,
         "beside the only registered frame, the chain predicts with the observations' centroid velocity"),
    Rule("no-chain-gate-growth", "registration", "trajectory.chain_gate_grows", False,
         "while the motion rests on two registered frames, the chain's 1 m gate grows with the extrapolation"),
    Rule("no-motion-outliers", "registration", "trajectory.motion_outliers", False,
         "registrations > 1 m off the constant-velocity prediction (the reference too) left to the chain, before and after it"),
    Rule("no-segments", "registration", "trajectory.min_segment_frames", 0,
         "unregistered observations that register together (>= 3 frames) form a segment (and are linked back)"),
    Rule("no-segment-link", "registration", "trajectory.link_segments.enabled", False,
         "split segments joined back to their instance through the vehicle's box"),
    Rule("with-out-of-view", "registration", "trajectory.out_of_view_frames", 20,
         "a vehicle's track carried through the frames where only the lidar saw it (off by default)", default_on=False),
    Rule("with-people-centroid", "registration", "trajectory.people_method", "centroid",
         "pedestrians placed by their points' centroids instead of registered (off by default)", default_on=False),
    # Lifting (new lifting, features and registration per street).
    Rule("full-erosion", "lifting", "lifting.min_kept_area", 0.0,
         "masks eroded less where 3 px would remove more than half of a small mask"),
    Rule("with-ground-neighbourhood", "lifting", "masks.lidar_motion.ground_neighbourhood", 2.0,
         "lidar motion's ground no higher than the lowest cell within 2 m + 0.15 m (off by default)", default_on=False),
    Rule("with-thin-people", "lifting", "masks.lidar_motion.thin_max_height", 1.5,
         "lidar motion keeps clusters thinner than min_footprint that span at most 1.5 m in height (off by default)",
         default_on=False),
]
RULE_BY_NAME = {r.name: r for r in RULES}


def _paper(c: PreprocessConfig) -> PreprocessConfig:
    """Every rule of ``RULES`` off at once (those off by default stay off)."""
    for rule in RULES:
        if rule.default_on:
            c = rule.off(c)
    return c


# Rules whose removal alone had no measurable effect on seeds 100-109: the variant
# ``no-neutral-five`` switches them off together (redundant rules can cover for each other).
NEUTRAL_FIVE = ("no-turning-curvature", "no-gross-yaw", "no-repose", "no-vertical-cap", "two-sided")


def variant_configs(base: PreprocessConfig) -> dict[str, tuple[str, PreprocessConfig]]:
    """``{name: (stage, config)}``: ``default``, one per rule, ``no-neutral-five``,
    ``no-tilt-limit-rescore`` and ``paper``."""
    out = {"default": ("smoothing", base)}
    out.update({r.name: (r.stage, r.off(base)) for r in RULES})
    joint = base
    for name in NEUTRAL_FIVE:
        joint = RULE_BY_NAME[name].off(joint)
    out["no-neutral-five"] = ("smoothing", joint)
    # The two registration rules whose removal alone helped, removed together.
    out["no-tilt-limit-rescore"] = ("registration", RULE_BY_NAME["no-rescore"].off(RULE_BY_NAME["no-tilt-limit"].off(base)))
    out["paper"] = ("lifting", _paper(base))
    return out


def _verdict(d_mota: float, mota_counts: tuple[int, int], d_corner: float, corner_counts: tuple[int, int]) -> str:
    """``pays`` when switching the rule off makes mean MOTA@2m worse by ``MOTA_EFFECT`` or more, or the
    mean corner error worse by ``CORNER_EFFECT`` (relative) or more, on more streets worse than better
    (of that metric); ``costs`` when off is better by those margins in the same way; both: ``mixed``;
    otherwise ``no measurable effect``."""
    (mw, mb), (cw, cb) = mota_counts, corner_counts
    pays = (d_mota <= -MOTA_EFFECT and mw > mb) or (d_corner >= CORNER_EFFECT and cw > cb)
    costs = (d_mota >= MOTA_EFFECT and mb > mw) or (d_corner <= -CORNER_EFFECT and cb > cw)
    return "mixed" if pays and costs else "pays" if pays else "costs" if costs else "no measurable effect"


def _stage_seconds(rows: list[dict], stage: str) -> str:
    """Mean seconds of ``stage`` over the streets where it was computed (``cached`` where none)."""
    s = [sec for r in rows for name, sec, cached in r["stages"] if name == stage and not cached]
    return f"{np.mean(s):.1f}" if s else "cached"


def table(results: dict[str, dict[int, dict]], order: list[str]) -> str:
    """The markdown table of the module docstring (deltas paired with ``default`` street by street)."""
    base = results["default"]
    lines = ["| variant (rule off) | streets | MOTA@2m | ΔMOTA | streets worse/better (MOTA) | MOTP@2m m "
             "| corner error m | Δcorner | streets worse/better (corner) | matched vehicles | registration/smoothing s | verdict |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in order:
        rows = {s: r for s, r in results.get(name, {}).items() if "error" not in r and s in base}
        failed = [s for s, r in results.get(name, {}).items() if "error" in r]
        if not rows:
            if failed:
                lines.append(f"| {name} | 0 (failed on {', '.join(map(str, failed))}) | | | | | | | | | | crashed |")
            continue
        seeds = sorted(rows)
        mota = np.array([rows[s]["mota"] for s in seeds])
        mota0 = np.array([base[s]["mota"] for s in seeds])
        corner = np.array([rows[s]["corner"] for s in seeds])
        corner0 = np.array([base[s]["corner"] for s in seeds])
        dm = mota - mota0
        rel = (corner - corner0) / corner0
        mota_counts = (int(np.sum(dm < -MOTA_TOL)), int(np.sum(dm > MOTA_TOL)))
        corner_counts = (int(np.nansum(rel > CORNER_TOL)), int(np.nansum(rel < -CORNER_TOL)))
        d_corner = np.nanmean(corner) / np.nanmean(corner0) - 1.0
        verdict = "—" if name == "default" else _verdict(float(dm.mean()), mota_counts, float(d_corner), corner_counts)
        motp = np.nanmean([rows[s]["motp"] for s in seeds])
        matched = sum(len(rows[s]["instances"]) for s in seeds)
        seconds = "/".join(_stage_seconds([rows[s] for s in seeds], stage) for stage in ("registration", "smoothing"))
        note = f" (failed on {', '.join(map(str, failed))})" if failed else ""
        lines.append(f"| {name} | {len(seeds)}{note} | {mota.mean():.3f} | {dm.mean():+.3f} | {mota_counts[0]}/{mota_counts[1]} "
                     f"| {motp:.3f} | {np.nanmean(corner):.3f} | {100 * d_corner:+.1f} % | {corner_counts[0]}/{corner_counts[1]} "
                     f"| {matched} | {seconds} | {verdict} |")
    return "\n".join(lines)


def main() -> None:
    ap = street_arguments(__doc__.splitlines()[0])
    ap.set_defaults(seeds=list(range(100, 110)))
    ap.add_argument("--variants", nargs="+", default=None,
                    help="rows to run (default: every rule, then paper); default is always run. "
                         f"Rules: {' '.join(r.name for r in RULES)} no-neutral-five no-tilt-limit-rescore paper")
    ap.add_argument("--registration-seeds", type=int, nargs="+", default=None,
                    help="streets for the variants that change registration or lifting (default: --seeds)")
    ap.add_argument("--json", type=Path, default=None, help="write every (variant, street) result here")
    ap.add_argument("--table-only", action="store_true",
                    help="print the table from the results stored in --work, computing nothing (rows on fewer streets where a run stopped)")
    args = ap.parse_args()
    if args.work is None:
        raise SystemExit("--work is required (streets, caches and results are kept there)")
    base = PreprocessConfig(masks=MaskConfig(kind="ground-truth"))
    configs = variant_configs(base)
    names = args.variants or [r.name for r in RULES] + ["no-neutral-five", "no-tilt-limit-rescore", "paper"]
    unknown = [n for n in names if n not in configs]
    if unknown:
        raise SystemExit(f"--variants: unknown {unknown}; choose from {list(configs)}")
    names = ["default"] + [n for n in names if n != "default"]
    # Cheap variants first (registration reused), then those that register again.
    rank = {"smoothing": 0, "registration": 1, "lifting": 2}
    names.sort(key=lambda n: (n != "default", rank[configs[n][0]]))
    reg_seeds = set(args.registration_seeds or args.seeds)
    results: dict[str, dict[int, dict]] = {n: {} for n in names}
    store = args.work / "results"
    store.mkdir(parents=True, exist_ok=True)
    streets = {} if args.table_only else {
        seed: (scene, train, cache) for seed, scene, train, cache in training_streets(args, "idsplat_rules_")}
    # Street by street for the variants that register again: stopped early, whole streets are done.
    jobs = [(n, s) for n in names if configs[n][0] == "smoothing" for s in args.seeds]
    jobs += [(n, s) for s in args.seeds if s in reg_seeds for n in names if configs[n][0] != "smoothing"]
    t_start = time.perf_counter()
    for i, (name, seed) in enumerate(jobs):
        stage, config = configs[name]
        key = hash_json({"config": asdict(config), "preset": args.preset, "seed": seed,
                         "train_fraction": args.train_fraction, "version": RESULTS_VERSION})
        path = store / f"{name}-{seed}-{key}.json"
        if path.is_file():
            results[name][seed] = json.loads(path.read_text())
            continue
        if args.table_only:
            continue
        scene, train, cache = streets[seed]
        t0 = time.perf_counter()
        try:
            r = evaluate(scene, train, config, cache)
        except Exception:  # a variant that crashes is a result too
            r = {"error": traceback.format_exc()}
            print(r["error"], flush=True)
        r.update({"variant": name, "seed": seed, "stage": stage, "config_key": key})
        path.write_text(json.dumps(r, indent=1))
        results[name][seed] = r
        computed = ",".join(st[0] for st in r.get("stages", []) if not st[2] and st[1] > 0.05) or "-"
        print(f"[{i + 1}/{len(jobs)} {time.perf_counter() - t_start:.0f} s] {name} seed {seed}: "
              + ("FAILED" if "error" in r else f"MOTA@2m {r['mota']:.3f} corner {r['corner']:.3f} m "
                 f"({len(r['instances'])} vehicles), {time.perf_counter() - t0:.0f} s, computed: {computed}"), flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"seeds": args.seeds, "registration_seeds": sorted(reg_seeds),
                                         "preset": args.preset, "results": {n: {str(s): r for s, r in v.items()}
                                                                            for n, v in results.items()}}, indent=1))
    order = names
    print()
    print(table(results, order))
    pooled = {n: aggregate([{2.0: TrackingMetrics(**m["summary"]["2"])} for m in v.values() if "summary" in m])
              for n, v in results.items() if any("summary" in m for m in v.values())}
    print("\npooled MOTA@2m (counts summed over the streets): "
          + ", ".join(f"{n} {flatten_metrics(p, (2.0,)).get('mota@2m', float('nan')):.3f}" for n, p in pooled.items()))


if __name__ == "__main__":
    main()
