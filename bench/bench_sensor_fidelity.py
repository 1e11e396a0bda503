"""Rolling shutter and view-dependent colour, with and without, on the built-in street with a
rolling-shutter camera rig: generates the street (``idsplat-synth --rolling-shutter-ms``), trains
each variant with ``ns-train``, evaluates with ``ns-eval`` and prints one table (PSNR, SSIM,
DPSNR and training wall time).

    .venv/bin/python -m bench.bench_sensor_fidelity --preset small --seed 100 --readout-ms 40 --steps 1500

Variants (``--variants``): ``full`` (both on, the defaults), ``no-rs`` (no rolling-shutter
compensation in rendering), ``no-view-dirs`` (no view directions in the RGB decoder) and
``neither``. They train with oracle instances, so that only the camera model differs.
``lifting-rs`` and ``lifting-no-rs`` train with self-supervised instances from the street's
ground-truth 2D masks. They differ only in whether the lifting stage projects lidar through the
rolling shutter. Each run is the plain command line a user would type (printed before it starts),
so every figure can be reproduced one by one.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.train_variants import print_table, synth_street, train_and_evaluate

VARIANTS = {
    "full": ["--pipeline.datamanager.instance-mode", "oracle"],
    "no-rs": ["--pipeline.datamanager.instance-mode", "oracle", "--pipeline.model.rolling-shutter", "False"],
    "no-view-dirs": ["--pipeline.datamanager.instance-mode", "oracle", "--pipeline.model.view-directions", "False"],
    "neither": ["--pipeline.datamanager.instance-mode", "oracle", "--pipeline.model.rolling-shutter", "False",
                "--pipeline.model.view-directions", "False"],
    "lifting-rs": ["--pipeline.datamanager.instance-mode", "self-supervised",
                   "--pipeline.datamanager.preprocess.masks.kind", "ground-truth"],
    "lifting-no-rs": ["--pipeline.datamanager.instance-mode", "self-supervised",
                      "--pipeline.datamanager.preprocess.masks.kind", "ground-truth",
                      "--pipeline.datamanager.preprocess.lifting.rolling-shutter", "False"],
}
COLUMNS = (("psnr", "PSNR"), ("ssim", "SSIM"), ("dpsnr", "DPSNR"), ("mota@2m", "MOTA@2m"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="small", help="built-in street preset (tiny, small, bench)")
    ap.add_argument("--seed", type=int, default=100, help="built-in street seed")
    ap.add_argument("--readout-ms", type=float, default=40.0, help="rolling-shutter readout of the street's cameras")
    ap.add_argument("--steps", type=int, default=1500, help="training steps of each variant (idsplat-fast)")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--output-dir", type=Path, default=Path("outputs/sensor_fidelity"))
    ap.add_argument("--skip-existing", action="store_true", help="reuse runs whose eval.json exists")
    ap.add_argument("--train-args", default="", help="extra ns-train options for every variant, one string (e.g. "
                    "\"--pipeline.model.lidar.enabled False\")")
    ap.add_argument("--tag", default="", help="suffix of the run folders (to keep runs with other --train-args apart)")
    args = ap.parse_args()
    data_dir = args.output_dir / "data"
    street = data_dir / f"synth_{args.preset}_rs{args.readout_ms:g}_{args.seed}"
    synth_street(data_dir, args.preset, args.seed, "--rolling-shutter-ms", f"{args.readout_ms:g}")
    rows = {variant: train_and_evaluate(street, f"{street.name}-{args.steps}{args.tag}-{variant}", args.output_dir,
                                        args.steps, VARIANTS[variant], args.train_args, args.skip_existing)
            for variant in args.variants}
    print_table(rows, COLUMNS)


if __name__ == "__main__":
    main()
