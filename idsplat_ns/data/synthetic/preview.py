"""Contact sheet of a written synthetic sequence: rows are frames, columns the three cameras.

`python -m idsplat_ns.data.synthetic.preview data/synth_small_0 docs/synthetic_small.jpg` makes
the picture in docs/synthetic.md (frames 0, middle and last; front-left, front, front-right).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from idsplat_ns.errors import IDSplatError, run_cli

SHEET_CAMERAS = ("front_left_camera", "front_camera", "front_right_camera")
"""Column order: left to right as seen from the driver's seat."""


def contact_sheet(sequence: Path, frames: list[int] | None = None, cameras=SHEET_CAMERAS) -> np.ndarray:
    """RGB uint8 [rows * H, 3 * W, 3] of `frames` (default: first, middle, last) by `cameras`."""
    sequence = Path(sequence)
    count = len(list((sequence / "camera" / cameras[0]).glob("*.jpg")))
    if count == 0:
        raise IDSplatError(f"{sequence}: no camera/{cameras[0]}/*.jpg; pass a folder written by idsplat-synth")
    frames = frames if frames is not None else [0, count // 2, count - 1]
    rows = []
    for k in frames:
        rows.append(np.concatenate([np.asarray(Image.open(sequence / "camera" / cam / f"{k:02d}.jpg").convert("RGB"))
                                    for cam in cameras], 1))
    return np.concatenate(rows, 0)


def _main() -> None:
    p = argparse.ArgumentParser(prog="python -m idsplat_ns.data.synthetic.preview", description=__doc__.splitlines()[0])
    p.add_argument("sequence", type=Path, help="a synth_<preset>_<seed> folder")
    p.add_argument("out", type=Path, help="JPEG to write")
    p.add_argument("--frames", type=int, nargs="+", default=None, help="frame indices (default: first, middle, last)")
    args = p.parse_args()
    Image.fromarray(contact_sheet(args.sequence, args.frames)).save(args.out, quality=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    run_cli(_main)
