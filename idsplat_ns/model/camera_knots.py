"""Parameters held per training image ("knots") and read at any time of the same camera.

A per-image correction (colour, pose) is learned only where there is a training image. Any other
time of that camera (its held-out frames, the viewer's slider) takes the value linearly interpolated
between the camera's two nearest training images in time, clamped at the ends; a camera without
training images has none. The interpolation is what makes held-out frames comparable without
looking at them. Shared by :mod:`idsplat_ns.model.exposure` and
:mod:`idsplat_ns.model.camera_refinement`.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
import torch
from torch import Tensor, nn


def interpolation_weights(knots: np.ndarray, time: float) -> tuple[int, int, float]:  # knots: [K] sorted, K >= 1
    """``(i, j, w)``: the value at ``time`` is ``(1 - w) v[i] + w v[j]`` (clamped outside the knots)."""
    k = int(knots.shape[0])
    if k == 1:
        return 0, 0, 0.0
    j = int(np.searchsorted(knots, time, side="right"))
    j = min(max(j, 1), k - 1)
    t0, t1 = float(knots[j - 1]), float(knots[j])
    w = min(max((time - t0) / (t1 - t0), 0.0), 1.0) if t1 > t0 else 0.0
    return j - 1, j, w


def interior_knots(times: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For every knot with a neighbour on both sides in its camera (``times`` [K]: all cameras'
    sorted knot times, camera ``c``'s at ``starts[c]:starts[c + 1]``): its index, its neighbours'
    indices and the weight of the later neighbour in the linear interpolation at its time. Each [M]."""
    middle = np.concatenate([np.arange(s + 1, e - 1) for s, e in zip(starts[:-1], starts[1:])] + [np.zeros(0)]).astype(np.int64)
    before, after = middle - 1, middle + 1
    weight = (times[middle] - times[before]) / (times[after] - times[before]) if len(middle) else np.zeros(0)
    return middle, before, after, weight.astype(np.float32)


class CameraKnots(nn.Module):
    """The knots' times, camera by camera; subclasses add one parameter row per knot."""

    def __init__(self, knot_times: Sequence[np.ndarray]) -> None:
        """``knot_times[c]``: the times [s] of camera ``c``'s training images (any order; repeats
        are one knot)."""
        super().__init__()
        per_camera = [np.unique(np.asarray(t, dtype=np.float64)) for t in knot_times]
        starts = np.concatenate([[0], np.cumsum([len(t) for t in per_camera])]).astype(np.int64)
        times = np.concatenate(per_camera) if per_camera else np.zeros(0)
        self.register_buffer("times", torch.from_numpy(times))  # [K] all cameras' knots, camera by camera
        self.register_buffer("starts", torch.from_numpy(starts))  # [C + 1] camera c's knots: starts[c]:starts[c+1]
        # Host copies: where a render falls between the knots is decided without reading the device.
        self._host_times, self._host_starts = times, starts
        middle, before, after, weight = interior_knots(times, starts)
        # Not saved: a checkpoint's knot times give them back (``like``).
        for name, value in (("_middle", middle), ("_before", before), ("_after", after)):
            self.register_buffer(name, torch.from_numpy(value), persistent=False)  # [M] knot indices
        self.register_buffer("_after_weight", torch.from_numpy(weight), persistent=False)  # [M]

    @classmethod
    def like(cls, state_dict: dict, prefix: str):
        """An instance of the checkpoint's shape (its knots), to load ``state_dict`` into."""
        times, starts = state_dict[prefix + "times"], state_dict[prefix + "starts"]
        return cls([times[int(starts[c]):int(starts[c + 1])].cpu().numpy() for c in range(len(starts) - 1)])

    @classmethod
    def for_images(cls, images, camera_names: Sequence[str]):
        """Knots at the times of ``images`` (the training images: ``camera`` and ``time`` [s]),
        one row per camera of ``camera_names``."""
        times: list[list[float]] = [[] for _ in camera_names]
        for im in images:
            times[list(camera_names).index(im.camera)].append(float(im.time))
        return cls([np.asarray(t) for t in times])

    @property
    def num_cameras(self) -> int:
        return len(self._host_starts) - 1

    @property
    def num_knots(self) -> int:
        return len(self._host_times)

    def value_at(self, values: Tensor, sensor: int, time: Optional[float]) -> Optional[Tensor]:  # values: [K, ...]
        """``values`` (one row per knot) of camera ``sensor`` at ``time`` [s]; None where the camera
        has no knots or there is no time."""
        if time is None or not 0 <= sensor < self.num_cameras:
            return None
        s, e = int(self._host_starts[sensor]), int(self._host_starts[sensor + 1])
        if e == s:
            return None
        i, j, w = interpolation_weights(self._host_times[s:e], float(time))
        if w == 0.0:
            return values[s + i]
        return (1.0 - w) * values[s + i] + w * values[s + j]

    def interpolation_residual(self, values: Tensor) -> Tensor:  # values: [K, ...] -> [M, ...]
        """For each knot with a neighbour on both sides in its camera: its value less the linear
        interpolation of its two neighbours' at its time, the error a held-out frame between two
        training images makes where the values do not vary smoothly (zero for values linear in time)."""
        w = self._after_weight.to(values).reshape(-1, *([1] * (values.dim() - 1)))
        return values[self._middle] - ((1.0 - w) * values[self._before] + w * values[self._after])
