"""Peak memory and load time of load_segment vs the frames, lidars and returns asked for (Waymo v1,
synthetic full-size lidar), beside the estimate that ns-train prints before loading.

Builds a segment by re-framing the real test frame (../shared/data/waymo/pvps_data_one_frame.tfrecord)
with full-size synthetic range images (TOP 64x2650, four 200x600 side lidars, two returns), then
loads N frames in a fresh process per N and prints peak RSS and the tracemalloc peak.

    .venv/bin/python -m bench.waymo_memory [--frames 20] [--ns 1 2 5 10]
    .venv/bin/python -m bench.waymo_memory --frames 6 --by-lidars 5   # lidar sets x returns, 5 frames
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

FRAME = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"

CHILD = r"""
import json, resource, sys, time, tracemalloc
from idsplat_ns.data.waymo import load_segment
path, start, end, lidar = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
lidars = sys.argv[5].split(",") if len(sys.argv) > 5 and sys.argv[5] else None
second = sys.argv[6] == "1" if len(sys.argv) > 6 else True
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
tracemalloc.start()
t = time.time()
scene = load_segment(path, start=start, end=end, load_lidar=lidar, lidars=lidars, second_return=second, progress=False)
elapsed = time.time() - t
_, peak = tracemalloc.get_traced_memory()
rays = sum(s.num_rays for s in scene.lidar)
print(json.dumps({"rss_import_mb": base / 1024, "rss_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "tracemalloc_peak_mb": peak / 2**20, "seconds": elapsed, "rays": rays}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="segment length (frames)")
    parser.add_argument("--ns", type=int, nargs="+", default=[1, 2, 5, 10], help="frames to load")
    parser.add_argument("--no-lidar", action="store_true", help="camera-only loads")
    parser.add_argument("--by-lidars", type=int, default=0, metavar="N",
                        help="instead: load N frames with each lidar set and first/both returns")
    args = parser.parse_args()
    from tqdm import tqdm

    from idsplat_ns.data.waymo.fixtures import write_synthetic_frames_to

    with tempfile.TemporaryDirectory() as tmp:
        seg = Path(tmp) / "segment.tfrecord"
        write_synthetic_frames_to(FRAME, seg, args.frames, progress=tqdm)
        size_mb = seg.stat().st_size / 2**20
        print(f"segment: {args.frames} frames, {size_mb:.0f} MB on disk ({size_mb / args.frames:.1f} MB/frame)")
        if args.by_lidars:
            by_lidars(seg, args.by_lidars)
            return
        print(f"{'N':>4} {'start':>5} {'rays':>10} {'RSS after import MB':>20} {'peak RSS MB':>12} {'tracemalloc peak MB':>20} {'s':>6}")
        for n in args.ns:
            for start in (0, args.frames - n):
                out = subprocess.run([sys.executable, "-c", CHILD, str(seg), str(start), str(start + n), "0" if args.no_lidar else "1"],
                                     capture_output=True, text=True, check=True)
                r = json.loads(out.stdout.strip().splitlines()[-1])
                print(f"{n:>4} {start:>5} {r['rays']:>10} {r['rss_import_mb']:>20.0f} {r['rss_peak_mb']:>12.0f} {r['tracemalloc_peak_mb']:>20.0f} {r['seconds']:>6.1f}")


def by_lidars(seg: Path, n: int) -> None:
    """A table over lidar sets and returns for ``n`` frames, with the pre-load estimate beside it."""
    from idsplat_ns.data.waymo.memory import estimate_segment_memory

    sets = [("TOP",), ("TOP", "FRONT"), ("TOP", "FRONT", "SIDE_LEFT", "SIDE_RIGHT", "REAR")]
    print("| lidars | returns | rays | peak RSS MB | tracemalloc peak MB | estimate MB | load s |")
    print("|---|---|---|---|---|---|---|")
    for names in sets:
        for second in (False, True):
            out = subprocess.run([sys.executable, "-c", CHILD, str(seg), "0", str(n), "1", ",".join(names), "1" if second else "0"],
                                 capture_output=True, text=True, check=True)
            r = json.loads(out.stdout.strip().splitlines()[-1])
            est = estimate_segment_memory(seg, None, list(names), second, 0, n).bytes / 2**20
            print(f"| {' '.join(names)} | {'both' if second else 'first'} | {r['rays']:,} | {r['rss_peak_mb']:.0f} | "
                  f"{r['tracemalloc_peak_mb']:.0f} | {est:.0f} | {r['seconds']:.1f} |")


if __name__ == "__main__":
    main()
