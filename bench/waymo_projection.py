"""Waymo 3D boxes projected with the project's camera model vs Waymo's own projected_lidar_labels.

For each laser label visible in a camera, the 8 box corners go through load_segment's scene (track
pose, camera_to_world, intrinsics with distortion); the clamped axis-aligned rectangle is compared
edge by edge with Waymo's projected_lidar_labels on the real test frame.

    .venv/bin/python -m bench.waymo_projection
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from idsplat_ns.data.waymo import load_segment
from idsplat_ns.data.waymo.projection_check import box_projection_errors

FRAME = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


def main() -> None:
    scene = load_segment(FRAME)
    print(f"{'camera':<12} {'boxes':>5} {'median px':>10} {'p90 px':>8} {'max px':>9} {'max px (r2<0.8)':>16}")
    all_err, all_in = [], []
    for im in scene.images:
        errs, r2 = box_projection_errors(im, scene.tracks)
        inside = errs[r2 < 0.8]
        all_err.append(errs)
        all_in.append(inside)
        print(f"{im.camera:<12} {len(errs):>5} {np.median(errs):>10.3f} {np.percentile(errs, 90):>8.3f} {errs.max():>9.1f} {inside.max():>16.3f}")
    e, i = np.concatenate(all_err), np.concatenate(all_in)
    print(f"{'all':<12} {len(e):>5} {np.median(e):>10.3f} {np.percentile(e, 90):>8.3f} {e.max():>9.1f} {i.max():>16.3f}")


if __name__ == "__main__":
    main()
