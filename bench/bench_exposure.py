"""Per-image colour correction, with and without, on built-in streets with and without
auto-exposure drift: generates each street (``idsplat-synth --exposure-drift``), trains each
variant with ``ns-train idsplat-fast`` (oracle instances, so that only the camera model differs),
evaluates with ``ns-eval`` and prints one table (held-out PSNR, SSIM, DPSNR, training wall time).

    .venv/bin/python -m bench.bench_exposure --preset varied --seeds 100 101 --drift 0.3

Held-out images carry the drift too: the correction there is interpolated in time from the same
camera's training images, never fitted to the image being scored.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.train_variants import print_table, synth_street, train_and_evaluate

VARIANTS = {
    "off": ["--pipeline.datamanager.instance-mode", "oracle", "--pipeline.model.exposure", "False"],
    "on": ["--pipeline.datamanager.instance-mode", "oracle", "--pipeline.model.exposure", "True"],
}
COLUMNS = (("psnr", "PSNR"), ("ssim", "SSIM"), ("dpsnr", "DPSNR"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="varied", help="built-in street preset")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101], help="built-in street seeds (report: 100 and up)")
    ap.add_argument("--drift", type=float, default=0.3, help="exposure drift of the drifting copy (gains 1 -/+ drift)")
    ap.add_argument("--steps", type=int, default=1500, help="training steps of each variant (idsplat-fast)")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--output-dir", type=Path, default=Path("outputs/exposure"))
    ap.add_argument("--skip-existing", action="store_true", help="reuse runs whose eval.json exists")
    args = ap.parse_args()
    data_dir = args.output_dir / "data"
    rows = {}
    for seed in args.seeds:
        for drift in (0.0, args.drift):
            extra = ["--exposure-drift", f"{drift:g}"] if drift else []
            synth_street(data_dir, args.preset, seed, *extra)
            street = data_dir / (f"synth_{args.preset}_ex{drift:g}_{seed}" if drift else f"synth_{args.preset}_{seed}")
            for variant in args.variants:
                name = f"{street.name}-{args.steps}-{variant}"
                rows[f"seed {seed}, drift {drift:g}, {variant}"] = train_and_evaluate(
                    street, name, args.output_dir, args.steps, VARIANTS[variant], skip_existing=args.skip_existing)
    print_table(rows, COLUMNS, first="street, correction")


if __name__ == "__main__":
    main()
