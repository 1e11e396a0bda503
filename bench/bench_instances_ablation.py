"""Instance-decomposition ablations on the synthetic street, side by side (the paper's Table 6 a-d
as switches), plus the runner's cache reuse.

For each variant: noisy ground-truth masks (unless stated) -> lifting -> features -> registration,
then the median translation / rotation errors of moving vehicles against the ground-truth tracks
(frames where the instance has >= 50 lidar points; before smoothing), pooled over the seeds.

    .venv/bin/python -m bench.bench_instances_ablation --preset tiny --seeds 0 1 2 3
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from idsplat_ns.data.pandaset import load_sequence
from idsplat_ns.data.synthetic import generate_sequence
from idsplat_ns.instances.features.config import FeatureConfig
from idsplat_ns.instances.lifting import LiftingConfig
from idsplat_ns.instances.masks.config import MaskConfig
from idsplat_ns.instances.masks.perturb import MaskNoiseConfig
from idsplat_ns.instances.masks.precomputed import PrecomputedMasksConfig
from idsplat_ns.instances.registration import RegistrationConfig
from idsplat_ns.instances.runner import PreprocessConfig, run_preprocessing
from idsplat_ns.eval.instance_pose_errors import summarise_errors
from idsplat_ns.instances.trajectory_config import TrajectoryConfig


def variants(root: Path, seed: int) -> dict[str, PreprocessConfig]:
    extras = root / "idsplat_extras"
    masks = MaskConfig(kind="precomputed", precomputed=PrecomputedMasksConfig(extras / "instance_masks", extras / "instances.json"))
    base = PreprocessConfig(masks=masks, mask_noise=MaskNoiseConfig(seed=seed), features=FeatureConfig(kind="daisy"), smoothing=None)
    return {
        "full (DAISY)": base,
        "a) no erosion": replace(base, lifting=LiftingConfig(erosion_px=0)),
        "b) no DBSCAN": replace(base, lifting=LiftingConfig(use_dbscan=False)),
        "c) centroid, no registration": replace(base, trajectory=TrajectoryConfig(method="centroid")),
        "d) RGB features": replace(base, features=FeatureConfig(kind="rgb")),
        "FPFH features": replace(base, features=FeatureConfig(kind="fpfh")),
        "RANSAC only (no ICP)": replace(base, trajectory=TrajectoryConfig(registration=RegistrationConfig(icp_iterations=0))),
        "clean GT masks": replace(base, mask_noise=None),
        "oracle GT boxes": replace(base, masks=MaskConfig(kind="gt_boxes"), mask_noise=None),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="tiny")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--work", type=Path, default=None, help="folder for sequences and caches (default: a temporary one)")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="idsplat_bench_"))
    rows: dict[str, dict] = {}
    cache_rows = []
    for seed in args.seeds:
        root = generate_sequence(work / "data", preset=args.preset, seed=seed, progress=False)
        scene = load_sequence(root)
        for name, cfg in variants(root, seed).items():
            cache = work / f"cache_{seed}"
            t0 = time.perf_counter()
            res = run_preprocessing(scene, cfg, cache, progress=False, verbose=False)
            first = time.perf_counter() - t0
            s = summarise_errors(scene, res.tracks, min_points=50)
            r = rows.setdefault(name, {"t": [], "r": [], "matched": 0, "moving": 0, "reg_s": 0.0})
            for e in s.per_instance:
                keep = e.point_counts >= 50
                r["t"] += e.translation[keep].tolist()
                r["r"] += e.rotation_deg[keep].tolist()
            r["matched"] += s.matched_tracks
            r["moving"] += s.moving_vehicle_tracks
            r["reg_s"] += sum(t.seconds for t in res.timings if t.name == "registration")
            if name == "full (DAISY)":
                t0 = time.perf_counter()
                again = run_preprocessing(scene, cfg, cache, progress=False, verbose=False)
                second = time.perf_counter() - t0
                cache_rows.append((seed, first, second, all(t.cached for t in again.timings if t.name in ("mask generation", "point painting", "features", "registration"))))
    print(f"\nInstance ablations, synthetic street preset '{args.preset}', seeds {args.seeds} (moving vehicles, frames with >= 50 points, before smoothing)")
    print(f"{'variant':<30}{'median t [m]':>13}{'median rot [deg]':>18}{'frames':>8}{'matched':>9}{'reg. [s]':>10}")
    for name, r in rows.items():
        t = np.median(r["t"]) if r["t"] else float("nan")
        rot = np.median(r["r"]) if r["r"] else float("nan")
        print(f"{name:<30}{t:>13.3f}{rot:>18.2f}{len(r['t']):>8}{r['matched']:>5}/{r['moving']:<3}{r['reg_s']:>10.1f}")
    print(f"\nCache reuse (full variant): {'seed':>4}{'first run [s]':>15}{'second run [s]':>16}  all stages cached")
    for seed, first, second, ok in cache_rows:
        print(f"{'':<28}{seed:>4}{first:>15.2f}{second:>16.2f}  {ok}")


if __name__ == "__main__":
    main()
