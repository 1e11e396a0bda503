"""Held-out lidar evaluation: the Table-2 metrics (:mod:`idsplat_ns.eval.lidar_metrics`) of each
rendered sweep, averaged over the held-out sweeps, and what the data cannot measure."""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.scene import Scene
from idsplat_ns.eval.lidar_metrics import lidar_metrics
from idsplat_ns.model.lidar_supervision import SweepRender

RAYDROP_NOTE = (
    "lidar ray-drop accuracy not computed: the data has no rays without a return to compare with "
    "(PandaSet layout stores returns only; Waymo range images and the built-in street have them)"
)


def has_drop_labels(sweeps: list[LidarSweep]) -> bool:
    """Whether the lidar data marks rays that returned nothing: without any, every ray counts as
    returned and a ray-drop accuracy would only measure how often the model predicts a drop."""
    return any(s.num_rays > 0 and not bool(np.all(s.returned)) for s in sweeps)


def sweep_metrics(render: SweepRender, drop_threshold: float = 0.5, drop_labels: bool = True) -> dict[str, float]:
    """Table-2 lidar metrics of one rendered sweep, named ``lidar_*`` for evaluation output; the
    ray-drop accuracy only with ``drop_labels`` (see :func:`has_drop_labels`)."""
    rays = render.rays
    m = lidar_metrics(
        render.range, render.intensity, render.ray_drop_prob, rays.ranges.numpy(), rays.intensities.numpy(),
        rays.returned.numpy(), rays.origins.numpy(), rays.directions.numpy(), drop_threshold=drop_threshold,
    )  # fmt: skip
    out = {
        "lidar_depth_median_sq_err": m["depth_median_sq"],
        "lidar_intensity_rmse": m["intensity_rmse"],
        "lidar_raydrop_acc": m["ray_drop_accuracy"],
        "lidar_chamfer": m["chamfer"],
    }
    if not drop_labels:
        del out["lidar_raydrop_acc"]
    return out


def sweep_range_errors(render: SweepRender, drop_threshold: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Measured range [K] and absolute range error [K] of the rays that returned in the data and
    are predicted returned: the ray set of the depth metric."""
    rays = render.rays
    both = rays.returned.numpy().astype(bool) & (np.asarray(render.ray_drop_prob) < drop_threshold)
    gt = rays.ranges.numpy().astype(np.float64)[both]
    return gt, np.abs(np.asarray(render.range, dtype=np.float64)[both] - gt)


def held_out_lidar_metrics(
    scene: Scene,
    sweeps: list[LidarSweep],
    render: Callable[[LidarSweep], SweepRender],
    drop_threshold: float = 0.5,
    advance: Callable[[], None] = lambda: None,
    on_render: Optional[Callable[[SweepRender], None]] = None,
) -> tuple[dict[str, float], Optional[str]]:
    """Lidar metrics averaged over ``sweeps`` (NaN sweeps left out; a metric NaN in every sweep
    is absent), with ``lidar_num_sweeps``; and a one-line note on what the data cannot measure
    (None when everything was measured). ``render`` renders one sweep; ``advance`` is called after
    each (a progress bar); ``on_render`` receives each rendered sweep (e.g. to collect errors)."""
    if not sweeps:
        return {}, None
    drop_labels = has_drop_labels(scene.lidar)
    per_sweep = []
    for sweep in sweeps:
        rendered = render(sweep)
        per_sweep.append(sweep_metrics(rendered, drop_threshold, drop_labels))
        if on_render is not None:
            on_render(rendered)
        advance()
    out: dict[str, float] = {}
    for key in per_sweep[0]:
        values = np.array([m[key] for m in per_sweep], dtype=np.float64)
        finite = values[np.isfinite(values)]
        if finite.size:
            out[key] = float(finite.mean())
    out["lidar_num_sweeps"] = len(per_sweep)
    return out, None if drop_labels else RAYDROP_NOTE
