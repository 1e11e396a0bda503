"""DPSNR of the rules beyond the paper whose ablation without training was mixed (switching them off
raised MOTA@2m but worsened the box-corner error, ``docs/reports/2026-11-27-rule-ablation.md``): each variant is
trained with ``ns-train idsplat-fast`` (self-supervised, instances from the street's ground-truth
2D masks, as the ablation) and evaluated with ``ns-eval``, beside the defaults and the defaults
with another training seed (``default-seed``: how much two runs of one configuration differ).
Prints one table per street and the mean over the streets (PSNR, DPSNR, its change from the
defaults, MOTA@2m and MOTP@2m after training, training wall time).

    nice -n 5 env OMP_NUM_THREADS=1 .venv/bin/python -m bench.bench_rule_dpsnr --seeds 100 101 102 --steps 600

Variants of one street can run in two processes at once (``--variants``, each writes its own
folder); ``--skip-existing`` then prints the whole table from the stored runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.train_variants import mean_rows, synth_street, train_and_evaluate
from bench.bench_rule_ablation import RULE_BY_NAME, Rule
from bench.streets import config_names

MIXED = ("no-vertical-motion", "no-tilt-motion", "no-heading-prior", "no-degenerate", "no-sparse-views",
         "no-refit", "no-segments")
COMMON = ["--pipeline.datamanager.instance-mode", "self-supervised",
          "--pipeline.datamanager.preprocess.masks.kind", "ground-truth"]
PREFIX = "--pipeline.datamanager.preprocess."
SMOOTHING_SUBCOMMAND = "pipeline.datamanager.preprocess.smoothing:smoothing-config"


def rule_arguments(rule: Rule) -> tuple[list[str], list[str]]:
    """The ``ns-train`` arguments that switch ``rule`` off: (before the dataparser, after ``--data``).
    Smoothing is an optional config, so its options follow its subcommand after the dataparser."""
    names = config_names(rule.path)
    flag = PREFIX + ".".join(n.replace("_", "-") for n in names)
    value = str(rule.value)  # None, True, False and numbers as tyro reads them
    if names[0] == "smoothing":
        return [], [SMOOTHING_SUBCOMMAND, flag, value]
    return [flag, value], []


def variant_arguments(name: str) -> tuple[list[str], list[str]]:
    if name == "default":
        return [], []
    if name == "default-seed":
        return ["--machine.seed", "1"], []
    return rule_arguments(RULE_BY_NAME[name])


COLUMNS = (("psnr", "PSNR"), ("dpsnr", "DPSNR"), ("delta", "ΔDPSNR"), ("mota@2m", "MOTA@2m"), ("motp@2m", "MOTP@2m m"))


def _table(rows: dict[str, dict], first: str) -> None:
    header = [first] + [t for _, t in COLUMNS] + ["train wall s"]
    print("\n| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for name, r in rows.items():
        cells = [name] + [("-" if k not in r else f"{r[k]:+.2f}" if k == "delta" else f"{r[k]:.3f}") for k, _ in COLUMNS]
        print("| " + " | ".join(cells + [f"{r['train_s']:.0f}"]) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102])
    ap.add_argument("--steps", type=int, default=600, help="training steps of each variant (idsplat-fast)")
    ap.add_argument("--variants", nargs="+", default=["default", "default-seed", *MIXED],
                    choices=["default", "default-seed", *RULE_BY_NAME])
    ap.add_argument("--output-dir", type=Path, default=Path("outputs/rule_dpsnr"))
    ap.add_argument("--train-args", default="--pipeline.model.lidar.enabled False",
                    help="extra ns-train options for every variant, one string (default: camera only)")
    ap.add_argument("--skip-existing", action="store_true", help="reuse runs whose eval.json exists")
    args = ap.parse_args()
    data_dir = args.output_dir / "data"
    per_seed: dict[str, list[dict]] = {v: [] for v in args.variants}
    for seed in args.seeds:
        street = data_dir / f"synth_{args.preset}_{seed}"
        synth_street(data_dir, args.preset, seed)
        rows = {}
        for variant in args.variants:
            before, after = variant_arguments(variant)
            rows[variant] = train_and_evaluate(street, f"{street.name}-{args.steps}-{variant}", args.output_dir, args.steps,
                                               COMMON + before, args.train_args, args.skip_existing, after)
        for variant, r in rows.items():
            if "default" in rows:
                r["delta"] = r["dpsnr"] - rows["default"]["dpsnr"]
            per_seed[variant].append(r)
        print(f"\nseed {seed}")
        _table(rows, "variant")
    means = mean_rows(per_seed)
    for variant, results in per_seed.items():
        if "delta" in means[variant]:
            worse = sum(r["delta"] < 0 for r in results)
            means[variant]["streets"] = f"{worse}/{len(results) - worse}"
    print(f"\nmean over seeds {' '.join(map(str, args.seeds))} (streets with lower/higher DPSNR than the defaults)")
    _table(means, "variant")
    for variant, m in means.items():
        if "streets" in m:
            print(f"{variant}: DPSNR lower on {m['streets']} streets")


if __name__ == "__main__":
    main()
