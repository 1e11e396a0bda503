"""bench/bench_tracking.py's table of vehicle frames lost and position errors by distance to the ego."""

from __future__ import annotations

import math

from bench.bench_tracking import distance_table
from idsplat_ns.eval.object_diagnosis import ObjectRecord


def test_frames_and_errors_fall_in_their_distance_bands():
    a = ObjectRecord("a", "overtaking", "car", "vehicle", frames=[0, 1, 2, 3], tracked=[True, False, True, True],
                     distance_to_ego=[5.0, 8.0, 25.0, 95.0], error=[0.4, math.nan, 0.1, 0.3],
                     along_error=[-0.3, math.nan, 0.0, 0.3])
    b = ObjectRecord("b", "leading", "car", "vehicle", frames=[0, 1], tracked=[True, False],
                     distance_to_ego=[9.0, 45.0], error=[0.2, math.nan], along_error=[0.1, math.nan])
    rows = distance_table([a, b]).splitlines()
    assert rows[0] == "| vehicles | 0-10 m | 10-20 m | 20-40 m | 40-60 m | 60-80 m |"
    assert rows[2] == "| frames lost / counted | 1 / 3 | 0 / 0 | 0 / 1 | 1 / 1 | 0 / 1 |"  # 95 m: the last band
    assert rows[3] == "| median error of tracked frames, m | 0.30 | - | 0.10 | - | 0.30 |"
    assert rows[4] == "| 90th percentile of that error, m | 0.38 | - | 0.10 | - | 0.30 |"  # 0.2 + 0.9 * (0.4 - 0.2)
    assert rows[5] == "| 90th percentile of its part along the heading, m | 0.28 | - | 0.00 | - | 0.30 |"  # |-0.3|, 0.1
