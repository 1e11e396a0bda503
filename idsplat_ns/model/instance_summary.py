"""What a trained scene's instances are: time span, Gaussians, mean speed, size and a class guess.

Read from the tensors of :class:`~idsplat_ns.model.editing.SceneTensors` (no nerfstudio). The
size is the extent of the instance's opaque Gaussians (2nd to 98th percentile of their centres,
so stray splats do not inflate it) along the principal horizontal axes of its footprint: the
canonical frame of a self-supervised instance need not be aligned with the vehicle. The class
(vehicle, pedestrian, cyclist) is a guess from that size and the mean speed
(:func:`idsplat_ns.data.tracks.class_from_size_speed`, the rule of the lidar-motion source); it costs
nothing and is labelled a guess wherever it is shown. The class of the instance decomposition itself
(from the detector's label, the annotations or the lidar-motion source) is in its tracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from idsplat_ns.data.tracks import class_from_size_speed
from idsplat_ns.model.editing import SceneTensors

MIN_OPACITY = 0.3  # below this a Gaussian hardly shows and should not decide the size


@dataclass(frozen=True)
class InstanceSummary:
    instance_id: int
    first_time: float  # seconds, first valid step
    last_time: float  # seconds, last valid step
    num_gaussians: int
    mean_speed: float  # m/s over the valid span (path length / duration); 0 for a single step
    size: tuple[float, float, float]  # (length, width, height) metres, see the module doc
    class_guess: str  # vehicle / pedestrian / cyclist from size and speed, or unknown


def guess_class(length: float, width: float, speed: float = float("nan")) -> str:
    """``vehicle``, ``pedestrian`` or ``cyclist`` from the footprint (metres) and mean speed (m/s);
    ``unknown`` without Gaussians."""
    cls = class_from_size_speed(length, width, speed)
    return "unknown" if cls == "other" else cls


def instance_size(means: np.ndarray, opacities: np.ndarray) -> tuple[float, float, float]:
    """(length, width, height) of canonical centres [N, 3] with opacities [N] in (0, 1)."""
    pts = means[opacities >= MIN_OPACITY]
    if len(pts) < 4:
        pts = means
    if len(pts) < 2:
        return (float("nan"),) * 3
    xy = pts[:, :2] - pts[:, :2].mean(0)
    _, _, axes = np.linalg.svd(xy, full_matrices=False)  # rows: principal horizontal directions
    along = xy @ axes.T  # [N, 2]
    lo, hi = np.percentile(along, 2, axis=0), np.percentile(along, 98, axis=0)
    zlo, zhi = np.percentile(pts[:, 2], [2, 98])
    length, width = sorted((float(hi[0] - lo[0]), float(hi[1] - lo[1])), reverse=True)
    return length, width, float(zhi - zlo)


def summarise_instances(scene: SceneTensors) -> list[InstanceSummary]:
    """One summary per trajectory row, in row order."""
    if scene.trajectories is None:
        return []
    t = scene.trajectories
    times = t["frame_times"].double().numpy()
    positions = t["positions"].detach().double().numpy()  # [Z, F, 3]
    ids_g = scene.gaussians["instance_ids"].numpy()
    means = scene.gaussians["means"].detach().double().numpy()
    opac = torch.sigmoid(scene.gaussians["opacities"].detach()).double().numpy()
    out = []
    for z, iid in enumerate(scene.instance_ids):
        first, last = int(t["span_first"][z]), int(t["span_last"][z])
        mine = ids_g == iid
        size = instance_size(means[mine], opac[mine])
        if first >= 0 and last > first:
            path = np.linalg.norm(np.diff(positions[z, first : last + 1], axis=0), axis=1).sum()
            speed = float(path / (times[last] - times[first]))
        else:
            speed = 0.0
        out.append(InstanceSummary(
            instance_id=iid,
            first_time=float(times[max(first, 0)]), last_time=float(times[max(last, 0)]),
            num_gaussians=int(mine.sum()), mean_speed=speed, size=size,
            class_guess=guess_class(size[0], size[1], speed if last > first else float("nan")),
        ))
    return out
