"""Waymo 3D boxes projected with the project's camera model vs Waymo's own projected_lidar_labels.

For each laser label visible in a camera, the 8 box corners go through load_segment's scene (track
pose, camera_to_world, intrinsics with distortion); the clamped axis-aligned rectangle is compared
edge by edge with Waymo's projected_lidar_labels on the real test frame.

    .venv/bin/python bench/waymo_projection.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from idsplat_ns.data.tracks import box_corners
from idsplat_ns.data.waymo import load_segment

FRAME = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


def main() -> None:
    scene = load_segment(FRAME)
    print(f"{'camera':<12} {'boxes':>5} {'median px':>10} {'p90 px':>8} {'max px':>9} {'max px (r2<0.8)':>16}")
    all_err, all_in = [], []
    for im in scene.images:
        labels = im.metadata["projected_lidar_labels"]
        W, H = im.intrinsics.width, im.intrinsics.height
        errs, inside = [], []
        for tr in scene.tracks:
            box = labels.get(f"{tr.track_id}_{im.camera}")
            if box is None:
                continue
            corners = box_corners(tr.poses[0], tr.metadata["sizes"][0])
            proj = im.project(corners)
            if np.any(proj.depth <= 0.1):
                continue
            e = np.abs(np.concatenate([np.clip(proj.uv.min(0), 0, [W, H]), np.clip(proj.uv.max(0), 0, [W, H])]) - box)
            errs.append(e)
            cam = (corners - im.camera_to_world[:3, 3]) @ im.camera_to_world[:3, :3]
            if np.max(np.sum((cam[:, :2] / cam[:, 2:]) ** 2, 1)) < 0.8:
                inside.append(e)
        errs, inside = np.array(errs), np.array(inside)
        all_err.append(errs)
        all_in.append(inside)
        print(f"{im.camera:<12} {len(errs):>5} {np.median(errs):>10.3f} {np.percentile(errs, 90):>8.3f} {errs.max():>9.1f} {inside.max():>16.3f}")
    e, i = np.concatenate(all_err), np.concatenate(all_in)
    print(f"{'all':<12} {len(e):>5} {np.median(e):>10.3f} {np.percentile(e, 90):>8.3f} {e.max():>9.1f} {i.max():>16.3f}")


if __name__ == "__main__":
    main()
