"""Rolling shutter and view-dependent colour, with and without, on the built-in street with a
rolling-shutter camera rig: generates the street (``idsplat-synth --rolling-shutter-ms``), trains
each variant with ``ns-train``, evaluates with ``ns-eval`` and prints one table (PSNR, SSIM,
DPSNR and training wall time).

    .venv/bin/python bench/bench_sensor_fidelity.py --preset small --seed 100 --readout-ms 40 --steps 1500

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
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent
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


def _run(cmd: list[str]) -> float:
    print("$ " + " ".join(cmd), flush=True)
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    return time.perf_counter() - start


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
    _run([str(BIN / "idsplat-synth"), "--preset", args.preset, "--seed", str(args.seed), "--rolling-shutter-ms",
          f"{args.readout_ms:g}", "--out", str(data_dir), "--quiet"])  # a cache hit when it exists
    rows = {}
    for variant in args.variants:
        name = f"{street.name}-{args.steps}{args.tag}-{variant}"
        run_dir = args.output_dir / name / "idsplat-fast" / "run"
        eval_json = args.output_dir / name / "eval.json"
        timing = args.output_dir / name / "train_seconds.json"
        train_s = json.loads(timing.read_text())["train_s"] if timing.is_file() else float("nan")
        if not (args.skip_existing and eval_json.is_file()):
            train_s = _run([
                str(BIN / "ns-train"), "idsplat-fast", "--vis", "tensorboard", "--output-dir", str(args.output_dir),
                "--experiment-name", name, "--timestamp", "run", "--max-num-iterations", str(args.steps),
                *VARIANTS[variant], *shlex.split(args.train_args), "idsplat-pandaset", "--data", str(street),
            ])
            timing.write_text(json.dumps({"train_s": train_s}))
            _run([str(BIN / "ns-eval"), "--load-config", str(run_dir / "config.yml"), "--output-path", str(eval_json)])
        results = json.loads(eval_json.read_text())["results"]
        results["train_s"] = train_s
        rows[variant] = results
    header = ["variant"] + [title for _, title in COLUMNS] + ["train wall s"]
    print("\n| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for variant, r in rows.items():
        cells = [variant] + [f"{r[k]:.3f}" if k in r else "-" for k, _ in COLUMNS] + [f"{r['train_s']:.0f}"]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
