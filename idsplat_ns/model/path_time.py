"""A time for a camera that has none: the time of the nearest point on the recorded camera paths.

Why: nerfstudio builds some camera paths without times (``ns-render interpolate`` does, from the
dataset's poses), and a scene with moving instances has no single picture without a time. Rather
than render the static background alone, the model places such a camera in time by where it is:
each recorded camera (one polyline per sensor, through its images' centres in time order) is a
path through space and time; the camera's centre is projected onto the nearest segment of any of
them and the time is interpolated linearly along that segment. A path interpolated between
recorded images of the drive therefore gets the times of the drive, and a camera held still gets
the time at which the car passed there. No nerfstudio import here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class PathClock:
    """Nearest-point time lookup on recorded camera paths."""

    def __init__(self, centres: Sequence[np.ndarray], times: Sequence[np.ndarray]) -> None:
        """``centres[s]`` [F_s, 3] camera centres (metres) and ``times[s]`` [F_s] seconds of sensor s."""
        starts, ends, t0, t1 = [], [], [], []
        for c, t in zip(centres, times):
            c, t = np.asarray(c, np.float64).reshape(-1, 3), np.asarray(t, np.float64).reshape(-1)
            if len(c) == 0:
                continue
            order = np.argsort(t, kind="stable")
            c, t = c[order], t[order]
            if len(c) == 1:  # a single image: a segment of zero length
                c, t = np.repeat(c, 2, 0), np.repeat(t, 2)
            starts.append(c[:-1])
            ends.append(c[1:])
            t0.append(t[:-1])
            t1.append(t[1:])
        if not starts:
            raise ValueError("PathClock: needs at least one recorded camera position")
        self.a = np.concatenate(starts)  # [S, 3] segment starts
        self.b = np.concatenate(ends)  # [S, 3] segment ends
        self.t0 = np.concatenate(t0)  # [S]
        self.t1 = np.concatenate(t1)  # [S]

    def time_of(self, position: np.ndarray) -> float:
        """Seconds at the point of the recorded paths nearest to ``position`` [3]."""
        p = np.asarray(position, np.float64).reshape(3)
        ab = self.b - self.a
        denom = (ab * ab).sum(1)
        u = np.where(denom > 0, ((p - self.a) * ab).sum(1) / np.where(denom > 0, denom, 1.0), 0.0).clip(0.0, 1.0)
        nearest = self.a + u[:, None] * ab
        s = int(np.argmin(((nearest - p) ** 2).sum(1)))
        return float(self.t0[s] + u[s] * (self.t1[s] - self.t0[s]))
