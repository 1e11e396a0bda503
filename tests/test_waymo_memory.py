"""Memory while reading N frames grows with N, not with the segment's length."""

from __future__ import annotations

import gc
import tracemalloc
from pathlib import Path

import pytest

from idsplat_ns.data.waymo import load_segment
from idsplat_ns.data.waymo.fixtures import write_synthetic_segment

FRAME = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"
pytestmark = pytest.mark.skipif(not FRAME.is_file(), reason=f"real Waymo frame not found at {FRAME}")


def _peak_mb(path: Path, start: int, end: int) -> float:
    gc.collect()
    tracemalloc.start()
    scene = load_segment(path, start=start, end=end)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert scene.num_frames == end - start
    del scene
    return peak / 2**20


def test_peak_memory_follows_frames_asked_not_segment_length(tmp_path):
    kw = dict(top_width=400, side_shape=(40, 120))
    short = write_synthetic_segment(FRAME, tmp_path / "short.tfrecord", 3, **kw)
    long = write_synthetic_segment(FRAME, tmp_path / "long.tfrecord", 10, **kw)
    assert long.stat().st_size > 3 * short.stat().st_size
    two_of_short = _peak_mb(short, 0, 2)
    two_of_long = _peak_mb(long, 7, 9)  # frames in the middle: earlier records are skipped by seeking
    four_of_long = _peak_mb(long, 2, 6)
    six_of_long = _peak_mb(long, 2, 8)
    assert two_of_long < 1.15 * two_of_short  # same frames asked, 3.3x the segment: same peak
    # Linear in the frames asked: equal increments per two more frames (a fixed part is the
    # parsed record and the per-frame conversion temporaries).
    step1, step2 = four_of_long - two_of_long, six_of_long - four_of_long
    assert step1 > 0.1 * two_of_long and 0.7 < step2 / step1 < 1.3
