"""`idsplat-synth`: write the built-in synthetic street in the PandaSet layout."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from idsplat_ns.data.synthetic.config import PRESETS, SyntheticConfig, get_preset
from idsplat_ns.data.synthetic.generate import generate_sequence
from idsplat_ns.errors import run_cli


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="idsplat-synth",
        description="Render the built-in synthetic driving street (3 cameras, 64-beam lidar, ground truth) "
        "in the PandaSet on-disk layout.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="small", help="size of the sequence (default: small)")
    p.add_argument("--out", type=Path, required=True, help="folder that receives synth_<preset>_<seed>/")
    p.add_argument("--seed", type=int, default=0, help="random seed of the street layout and sensor noise")
    p.add_argument("--overwrite", action="store_true", help="replace an existing sequence made with other settings")
    p.add_argument(
        "--workers", type=int, default=None, help="processes rendering frames (default: 2 for 20+ frames, else 1)"
    )
    p.add_argument(
        "--pedestrians", type=int, default=None,
        help="walking pedestrians, the first crossing the road (default: the preset's; tiny 0, small 3, bench 4)",
    )
    p.add_argument(
        "--cyclists", type=int, default=None, help="cyclists in the lanes (default: the preset's; tiny 0, small 1, bench 2)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def config_from_args(preset: str, pedestrians: int | None, cyclists: int | None) -> SyntheticConfig:
    """The preset, with the counts of people replaced where given; a changed preset gets its own name
    (`small_p5c0`), so that its folder does not collide with the preset's."""
    config = get_preset(preset)
    counts = {
        "num_pedestrians": config.num_pedestrians if pedestrians is None else pedestrians,
        "num_cyclists": config.num_cyclists if cyclists is None else cyclists,
    }
    if counts["num_pedestrians"] == config.num_pedestrians and counts["num_cyclists"] == config.num_cyclists:
        return config
    name = f"{config.name}_p{counts['num_pedestrians']}c{counts['num_cyclists']}"
    return get_preset(dataclasses.replace(config, name=name, **counts))


def _main() -> None:
    args = _parser().parse_args()
    start = time.perf_counter()
    config = config_from_args(args.preset, args.pedestrians, args.cyclists)
    path = generate_sequence(
        args.out, config, args.seed, overwrite=args.overwrite, workers=args.workers, progress=not args.quiet
    )
    print(f"wrote {path} in {time.perf_counter() - start:.1f} s")


def main() -> None:
    """Console entry point (errors from bad options end in one line)."""
    run_cli(_main)


if __name__ == "__main__":
    main()
