"""Rigid against deformable pedestrians and cyclists on built-in streets (people with swinging legs
and pedalling): trains each variant with ``ns-train`` in oracle mode (the annotated tracks as
instances, so that only the model of the people differs), evaluates with ``ns-eval`` and prints
one table per street and the mean over the streets (PSNR, DPSNR of moving vehicles, pedestrians
and cyclists, training wall time).

    .venv/bin/python -m bench.bench_deformation --preset small --seeds 100 101 102 103 104 --steps 600 \\
        --train-args "--pipeline.model.lidar.enabled False"

Variants: ``rigid`` (every instance rigid, the paper) and ``deformable``
(``--pipeline.model.deformation.enabled True``: pedestrians and cyclists deform), both oracle;
``self-supervised`` (not run unless named: the default instances, from lidar motion, all rigid).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.train_variants import mean_rows, print_table, synth_street, train_and_evaluate

ORACLE = ["--pipeline.datamanager.instance-mode", "oracle"]
VARIANTS = {
    "rigid": ORACLE,
    "deformable": ORACLE + ["--pipeline.model.deformation.enabled", "True"],
    # The method itself: instances from lidar motion (no ground truth read), every one rigid.
    "self-supervised": ["--pipeline.datamanager.instance-mode", "self-supervised"],
}
COLUMNS = (("psnr", "PSNR"), ("dpsnr", "DPSNR veh."),
           ("dpsnr_pedestrian", "DPSNR ped."), ("dpsnr_cyclist", "DPSNR cyc."),
           ("mota@2m", "MOTA@2m veh."), ("pedestrian_mota@2m", "MOTA@2m ped."), ("cyclist_mota@2m", "MOTA@2m cyc."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small", help="built-in street preset (small and bench have people)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102, 103, 104])
    ap.add_argument("--steps", type=int, default=1500, help="training steps of each variant (idsplat-fast)")
    ap.add_argument("--variants", nargs="+", default=["rigid", "deformable"], choices=list(VARIANTS))
    ap.add_argument("--output-dir", type=Path, default=Path("outputs/deformation"))
    ap.add_argument("--skip-existing", action="store_true", help="reuse runs whose eval.json exists")
    ap.add_argument("--train-args", default="", help="extra ns-train options for every variant, one string")
    ap.add_argument("--tag", default="", help="suffix of the run folders (to keep runs with other --train-args apart)")
    args = ap.parse_args()
    data_dir = args.output_dir / "data"
    per_seed: dict[str, list[dict]] = {v: [] for v in args.variants}
    for seed in args.seeds:
        street = data_dir / f"synth_{args.preset}_{seed}"
        synth_street(data_dir, args.preset, seed)
        rows = {}
        for variant in args.variants:
            rows[variant] = train_and_evaluate(street, f"{street.name}-{args.steps}{args.tag}-{variant}", args.output_dir,
                                               args.steps, VARIANTS[variant], args.train_args, args.skip_existing)
            per_seed[variant].append(rows[variant])
        print(f"\nseed {seed}")
        print_table(rows, COLUMNS)
    means = mean_rows(per_seed)
    print(f"\nmean over seeds {' '.join(map(str, args.seeds))}")
    print_table(means, COLUMNS)


if __name__ == "__main__":
    main()
