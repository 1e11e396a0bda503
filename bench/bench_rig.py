"""What a real rig does to the data, and what the sensor corrections get back: on built-in streets
made clean and again with one rig defect each (``idsplat-synth --calibration-error-deg``,
``--exposure-drift``, ``--pose-noise``), trains ``ns-train idsplat-fast`` without and with the
corrections (``--pipeline.model.exposure``, ``--pipeline.model.camera-refinement``,
``--pipeline.model.pose-refinement``; oracle instances, so that only the camera model differs),
evaluates with ``ns-eval`` and prints one table (held-out PSNR, SSIM, DPSNR, training wall time).

    .venv/bin/python -m bench.bench_rig --preset varied --seeds 102 103

Held-out images carry the defect too: their corrections are the same camera's (calibration) or
interpolated in time from the same camera's training images (exposure, poses), never fitted to the
image being scored.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.train_variants import print_table, synth_street, train_and_evaluate

ORACLE = ["--pipeline.datamanager.instance-mode", "oracle"]

def _corrections(exposure: bool, calibration: bool, poses: bool) -> list[str]:
    return ORACLE + ["--pipeline.model.exposure", str(exposure), "--pipeline.model.camera-refinement", str(calibration),
                     "--pipeline.model.pose-refinement", str(poses)]


CORRECTIONS = {
    "off": _corrections(False, False, False),
    "exposure": _corrections(True, False, False),
    "calibration": _corrections(False, True, False),
    "poses": _corrections(False, False, True),
    "both": _corrections(True, True, False),
    "all": _corrections(True, True, True),
    # The per-image corrections drawn to their neighbours' interpolation (held-out frames get that).
    "both-smooth": _corrections(True, True, False) + ["--pipeline.model.exposure-smoothness", "1.0"],
    "all-smooth": _corrections(True, True, True) + ["--pipeline.model.exposure-smoothness", "1.0",
                                                    "--pipeline.model.pose-refinement-smoothness", "0.01"],
}
# Each defect: the idsplat-synth options that make it, and the suffix they give the street's name.
DEFECTS = {
    "clean": ([], ""),
    "calibration": (["--calibration-error-deg", "1.0", "0.5"], "_cal1x0.5"),
    "exposure": (["--exposure-drift", "0.3"], "_ex0.3"),
    "poses": (["--pose-noise", "0.5", "0.1"], "_pn0.5x0.1"),
}
COLUMNS = (("psnr", "PSNR"), ("ssim", "SSIM"), ("dpsnr", "DPSNR"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="varied", help="built-in street preset")
    ap.add_argument("--seeds", type=int, nargs="+", default=[102, 103], help="built-in street seeds (report: 100 and up)")
    ap.add_argument("--defects", nargs="+", default=list(DEFECTS), choices=list(DEFECTS), help="streets to make")
    ap.add_argument("--corrections", nargs="+", default=["off", "both"], choices=list(CORRECTIONS),
                    help="which corrections each street is trained with")
    ap.add_argument("--steps", type=int, default=1500, help="training steps of each variant (idsplat-fast)")
    ap.add_argument("--output-dir", type=Path, default=Path("outputs/rig"))
    ap.add_argument("--skip-existing", action="store_true", help="reuse runs whose eval.json exists")
    args = ap.parse_args()
    data_dir = args.output_dir / "data"
    rows = {}
    for seed in args.seeds:
        for defect in args.defects:
            options, suffix = DEFECTS[defect]
            synth_street(data_dir, args.preset, seed, *options)
            street = data_dir / f"synth_{args.preset}{suffix}_{seed}"
            for correction in args.corrections:
                name = f"{street.name}-{args.steps}-{correction}"
                rows[f"seed {seed}, {defect}, {correction}"] = train_and_evaluate(
                    street, name, args.output_dir, args.steps, CORRECTIONS[correction], skip_existing=args.skip_existing)
    print_table(rows, COLUMNS, first="street, corrections")


if __name__ == "__main__":
    main()
