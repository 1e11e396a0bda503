"""The average of per-image metrics over the held-out images, for ns-eval and the trainer's
evaluations: metrics that only some images have (DPSNR of a class needs moving objects of that
class in view) are averaged over those images, with their count; a metric no image has is absent."""

from __future__ import annotations

import numpy as np


def average_image_metrics(per_image: list[dict[str, float]], get_std: bool = False) -> dict:
    """Mean of each metric over the images that have it (``<key>_std`` with ``get_std``, sample
    standard deviation, 0 for one image); ``<key>_num_images`` where fewer images than all have it;
    ``num_images``; and ``render_mpix_per_s`` from the per-image ``num_rays_per_sec``."""
    keys = list(dict.fromkeys(k for m in per_image for k in m))
    result: dict = {}
    for key in keys:
        values = np.array([m[key] for m in per_image if key in m], dtype=np.float64)
        result[key] = float(values.mean())
        if get_std and key != "num_rays_per_sec":
            result[f"{key}_std"] = float(values.std(ddof=1)) if len(values) > 1 else 0.0
        if len(values) != len(per_image):
            result[f"{key}_num_images"] = len(values)
    result["num_images"] = len(per_image)
    if "num_rays_per_sec" in result:
        result["render_mpix_per_s"] = result.pop("num_rays_per_sec") / 1e6
    return result
